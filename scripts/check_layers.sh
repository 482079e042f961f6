#!/usr/bin/env bash
# The library's layering, checked: a header in include/orbitforge/<layer>/ may
# include headers of its own layer and of the layers listed before it, never of
# a later one. Prints every violation and exits 1 when there is one.
set -euo pipefail
cd "$(dirname "$0")/.."
layers=(core image geometry nn splat deform io train metrics pipeline audit)
rank() { local i; for i in "${!layers[@]}"; do [ "${layers[$i]}" = "$1" ] && { echo "$i"; return; }; done; echo -1; }
bad=0
for dir in include/orbitforge/*/; do
  layer=$(basename "$dir")
  r=$(rank "$layer")
  if [ "$r" -lt 0 ]; then echo "check_layers: $dir is not a known layer (${layers[*]})"; bad=1; continue; fi
  while IFS= read -r line; do
    file=${line%%:*}
    used=$(sed -E 's|.*#include "orbitforge/([a-z_]+)/.*|\1|' <<<"$line")
    u=$(rank "$used")
    if [ "$u" -lt 0 ] || [ "$u" -gt "$r" ]; then
      echo "check_layers: $file ($layer) includes orbitforge/$used/ (a later layer)"
      bad=1
    fi
  done < <(grep -rHE '#include "orbitforge/[a-z_]+/' "$dir" || true)
done
[ "$bad" -eq 0 ] && echo "check_layers: every header includes only its own or earlier layers (${layers[*]})"
exit "$bad"
