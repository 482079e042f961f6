#!/usr/bin/env bash
# Every public header compiles on its own, with only the include paths of the
# CMake target it belongs to, and no orbitforge::core header reaches stb or
# nlohmann-json (both sit in /usr/include on Debian, so compiling alone would not
# notice; the check reads the compiler's dependency list instead).
#
#   scripts/check_headers.sh [HEADER...]      (default: every header)
# Environment: CXX (default c++), EIGEN_INCLUDE (default /usr/include/eigen3),
# STB_INCLUDE (default /usr/include/stb), JOBS (default nproc).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cxx=${CXX:-c++}
eigen=${EIGEN_INCLUDE:-/usr/include/eigen3}
stb=${STB_INCLUDE:-/usr/include/stb}
jobs=${JOBS:-$(nproc)}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

if [ $# -gt 0 ]; then headers=("$@"); else
  mapfile -t headers < <(cd "$root/include" && find orbitforge -name '*.hpp' | sort)
fi

# target_of HEADER: core | io | pipeline (the folders of CMakeLists.txt's targets).
target_of() {
  case "$1" in
    orbitforge/io/*) echo io ;;
    orbitforge/pipeline/* | orbitforge/audit/* | orbitforge/orbitforge.hpp) echo pipeline ;;
    *) echo core ;;
  esac
}

check_one() {
  local h=$1 target flags name
  target=$(target_of "$h")
  flags=(-std=c++17 -fsyntax-only -Wall -Wextra -Werror -Wno-unused-function -I "$root/include" -isystem "$eigen")
  [ "$target" != core ] && flags+=(-isystem "$stb")
  name=$work/$(tr '/' '_' <<<"$h")
  printf '#include "%s"\n' "$h" >"$name.cpp"
  if ! "$cxx" "${flags[@]}" -MD -MF "$name.d" "$name.cpp" 2>"$name.err"; then
    echo "check_headers: $h ($target) does not compile on its own:"
    head -20 "$name.err"
    return 1
  fi
  if [ "$target" = core ] && grep -qE '(nlohmann/|stb_image)' "$name.d"; then
    echo "check_headers: $h (orbitforge::core) includes stb or nlohmann-json:"
    grep -oE '[^ ]*(nlohmann/|stb_image)[^ ]*' "$name.d" | head -3
    return 1
  fi
}
export -f check_one target_of
export root cxx eigen stb work

if printf '%s\n' "${headers[@]}" | xargs -P "$jobs" -I{} bash -c 'check_one "$1"' _ {}; then
  echo "check_headers: ${#headers[@]} headers compile on their own with their target's include paths"
else
  exit 1
fi
