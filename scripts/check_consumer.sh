#!/usr/bin/env bash
# A downstream project uses orbitforge three ways: find_package after install,
# FetchContent, and copied headers with the include paths the README names. The
# installed package and the copied headers build and run the two vendoring
# examples (examples/host_adaptor.cpp, examples/orbit_from_gl.cpp) and a
# core-only program (FetchContent: that program); the README's C++ snippets are
# compiled (and run, when they have a main) against the copied headers; the
# rendering examples are also built with ORBITFORGE_NO_SIMD and must agree.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cxx=${CXX:-c++}
run_all() {  # DIR
  "$1/consumer" >/dev/null
  "$1/orbit_from_gl" >/dev/null
  "$1/host_adaptor" "$work/host.png" >/dev/null
}
cmake -S "$root" -B "$work/build" -DORBITFORGE_BUILD_TESTS=OFF -DORBITFORGE_BUILD_EXAMPLES=OFF \
  -DCMAKE_INSTALL_PREFIX="$work/prefix" >/dev/null
cmake --install "$work/build" >/dev/null
for via in package fetch; do
  cmake -S "$root/tests/consumer" -B "$work/$via" -DORBITFORGE_VIA=$via -DCMAKE_PREFIX_PATH="$work/prefix" \
    -DORBITFORGE_SOURCE="$root" -DORBITFORGE_EXAMPLES="$root/examples" --no-warn-unused-cli >/dev/null
done
# The examples against the installed package; FetchContent's targets are the same
# files, so it builds the core-only program alone.
cmake --build "$work/package" --parallel "$(nproc)" >/dev/null
run_all "$work/package"
cmake --build "$work/fetch" --target consumer >/dev/null
"$work/fetch/consumer" >/dev/null

# Copied headers: orbitforge::core needs -I include -I /usr/include/eigen3 (xsimd
# is in /usr/include); io/ and pipeline/ add stb and nlohmann-json, also in
# /usr/include on Debian, and a program that writes PNG or SPZ links zlib.
mkdir -p "$work/copy/include"
cp -r "$root/include/orbitforge" "$work/copy/include/"
flags=(-std=c++17 -O1 -I "$work/copy/include" -I /usr/include/eigen3 -pthread)
libs=(-lz)
mkdir -p "$work/copied"
"$cxx" "${flags[@]}" "$root/tests/consumer/main.cpp" -o "$work/copied/consumer" &
"$cxx" "${flags[@]}" "$root/examples/orbit_from_gl.cpp" -o "$work/copied/orbit_from_gl" &
"$cxx" "${flags[@]}" "$root/examples/host_adaptor.cpp" -o "$work/copied/host_adaptor" "${libs[@]}"
wait
run_all "$work/copied"

# The scalar build (ORBITFORGE_NO_SIMD, core/config.hpp) of the two examples that
# render and differentiate: they must build, run, and print what the SIMD build
# printed (host_adaptor's gradients; quick_start's pixel and gradients, without
# its timing).
mkdir -p "$work/nosimd"
"$cxx" "${flags[@]}" "$root/examples/quick_start.cpp" -o "$work/copied/quick_start" & pid1=$!
"$cxx" "${flags[@]}" -DORBITFORGE_NO_SIMD "$root/examples/quick_start.cpp" -o "$work/nosimd/quick_start" & pid2=$!
"$cxx" "${flags[@]}" -DORBITFORGE_NO_SIMD "$root/examples/host_adaptor.cpp" -o "$work/nosimd/host_adaptor" "${libs[@]}" ||
  { echo "check_consumer: host_adaptor does not build with ORBITFORGE_NO_SIMD"; exit 1; }
wait $pid1 || { echo "check_consumer: quick_start does not build"; exit 1; }
wait $pid2 || { echo "check_consumer: quick_start does not build with ORBITFORGE_NO_SIMD"; exit 1; }
"$work/copied/host_adaptor" "$work/host_simd.png" >"$work/host_simd.txt"
"$work/nosimd/host_adaptor" "$work/host_nosimd.png" >"$work/host_nosimd.txt"
cmp -s "$work/host_simd.txt" "$work/host_nosimd.txt" ||
  { echo "check_consumer: host_adaptor prints other gradients with ORBITFORGE_NO_SIMD:"; cat "$work"/host_*simd.txt; exit 1; }
"$work/copied/quick_start" | sed 's/; [0-9.]* ms$//' >"$work/quick_simd.txt"
"$work/nosimd/quick_start" | sed 's/; [0-9.]* ms$//' >"$work/quick_nosimd.txt"
cmp -s "$work/quick_simd.txt" "$work/quick_nosimd.txt" ||
  { echo "check_consumer: quick_start prints other values with ORBITFORGE_NO_SIMD:"; cat "$work"/quick_*simd.txt; exit 1; }

# The README's ```cpp blocks, each a whole translation unit; the first is
# examples/quick_start.cpp verbatim.
python3 - "$root/README.md" "$work/snippets" "$root/examples/quick_start.cpp" <<'PY'
import os, re, sys
text = open(sys.argv[1]).read()
os.makedirs(sys.argv[2], exist_ok=True)
blocks = re.findall(r"```cpp\n(.*?)```", text, re.S)
if not blocks or blocks[0] != open(sys.argv[3]).read():
    sys.exit("check_consumer: the README's first C++ block is not examples/quick_start.cpp")
for i, b in enumerate(blocks):
    open(os.path.join(sys.argv[2], f"snippet{i}.cpp"), "w").write(b)
PY
n=0
for src in "$work"/snippets/snippet*.cpp; do
  if grep -q "int main" "$src"; then
    "$cxx" "${flags[@]}" "$src" -o "${src%.cpp}" "${libs[@]}" || { echo "check_consumer: README snippet $(basename "$src") does not build"; exit 1; }
    "${src%.cpp}" >/dev/null || { echo "check_consumer: README snippet $(basename "$src") fails when run"; exit 1; }
  else
    "$cxx" "${flags[@]}" -c "$src" -o "${src%.cpp}.o" || { echo "check_consumer: README snippet $(basename "$src") does not compile"; exit 1; }
  fi
  n=$((n + 1))
done
[ "$n" -ge 3 ] || { echo "check_consumer: expected at least 3 README snippets, found $n"; exit 1; }
echo "check_consumer: find_package, FetchContent and copied headers build and run the vendoring examples;" \
  "quick_start and host_adaptor with ORBITFORGE_NO_SIMD print what the SIMD build prints; $n README snippets compile"
