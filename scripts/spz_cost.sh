#!/usr/bin/env bash
# What SPZ costs on a reconstructed scene: the .spz size against the PLY's, and the
# PSNR of renders of the SPZ-decoded scene against those of the PLY, both against the
# frames the scene was trained on and against each other (same cameras, same
# renderer: the difference is the format's quantisation alone).
#
#   scripts/spz_cost.sh RUN_DIR [EVERY]    # RUN_DIR holds final.ply and vhat.json
#
# The cameras are every EVERY-th (default 8) frame of RUN_DIR/vhat.json (G1's training
# frames: R0 arc renders and completion frames, each with its orbit camera), at their
# own size, rendered with examples/render_orbit (float PFM, on the run's background
# from report.json, black without one) and compared with the frame's PNG. BUILD_DIR (default build) must hold the built
# ply_tool and render_orbit. Prints one line per view and a summary.
set -euo pipefail
run=${1:?usage: scripts/spz_cost.sh RUN_DIR [EVERY]}
every=${2:-8}
BUILD_DIR=${BUILD_DIR:-build}
tool="$BUILD_DIR/examples/ply_tool"
render="$BUILD_DIR/examples/render_orbit"
for f in "$tool" "$render" "$run/final.ply" "$run/vhat.json"; do
  [ -e "$f" ] || { echo "spz_cost: $f missing" >&2; exit 1; }
done
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
python3 - "$run/vhat.json" "$every" "$work/cameras.json" <<'EOF'
import json, sys
frames = json.load(open(sys.argv[1]))["frames"][::int(sys.argv[2])]
json.dump(frames, open(sys.argv[3], "w"))
EOF
bg=$(python3 -c 'import json, sys
try: print(",".join(str(v) for v in json.load(open(sys.argv[1]))["background"]["color"]))
except (OSError, KeyError, ValueError): print("0,0,0")' "$run/report.json")
echo "background $bg"
"$tool" convert "$run/final.ply" "$work/final.spz"
"$tool" convert "$work/final.spz" "$work/decoded.ply"
"$render" --ply "$run/final.ply" --camera "$work/cameras.json" --format pfm --background "$bg" --out "$work/ply" >/dev/null
"$render" --ply "$work/decoded.ply" --camera "$work/cameras.json" --format pfm --background "$bg" --out "$work/spz" >/dev/null
python3 - "$run" "$work/cameras.json" "$work/final.spz" "$work/ply" "$work/spz" <<'EOF'
import array, json, math, os, struct, sys, zlib
run, cams, spz, a_dir, b_dir = sys.argv[1:6]

def pfm(path):  # rows bottom to top, RGB float
    with open(path, 'rb') as f:
        f.readline()
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        data = array.array('f')
        data.frombytes(f.read())
    if (scale < 0) != (sys.byteorder == 'little'):
        data.byteswap()
    rows = [data[(h - 1 - y) * w * 3:(h - y) * w * 3] for y in range(h)]
    return w, h, [v for r in rows for v in r]

def png(path):  # 8-bit RGB or RGBA, not interlaced; returns RGB in [0, 1], rows top to bottom
    b = open(path, 'rb').read()
    pos, idat, w = 8, b'', 0
    while pos < len(b):
        n, kind = struct.unpack('>I4s', b[pos:pos + 8])
        chunk = b[pos + 8:pos + 8 + n]
        if kind == b'IHDR':
            w, h, depth, ctype = struct.unpack('>IIBB', chunk[:10])
            assert depth == 8 and ctype in (2, 6), f"{path}: PNG colour type {ctype}, depth {depth}"
            ch = 3 if ctype == 2 else 4
        elif kind == b'IDAT':
            idat += chunk
        pos += 12 + n
    raw, stride, out, prev = zlib.decompress(idat), w * ch, [], bytearray(w * ch)
    for y in range(h):
        f, line = raw[y * (stride + 1)], bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for i in range(stride):
            a = line[i - ch] if i >= ch else 0
            c = prev[i - ch] if i >= ch else 0
            up = prev[i]
            if f == 1: line[i] = (line[i] + a) & 255
            elif f == 2: line[i] = (line[i] + up) & 255
            elif f == 3: line[i] = (line[i] + (a + up) // 2) & 255
            elif f == 4:
                p = a + up - c
                pa, pb, pc = abs(p - a), abs(p - up), abs(p - c)
                line[i] = (line[i] + (a if pa <= pb and pa <= pc else up if pb <= pc else c)) & 255
        prev = line
        out.extend(line[x * ch + k] / 255.0 for x in range(w) for k in range(3))
    return w, h, out

def psnr(a, b):
    clip = lambda v: min(1.0, max(0.0, v))
    mse = sum((clip(x) - clip(y)) ** 2 for x, y in zip(a, b)) / len(a)
    return 10 * math.log10(1 / mse) if mse > 0 else float('inf')

rows = []
for i, cam in enumerate(json.load(open(cams))):
    name = f"{i:05d}.pfm"
    w, h, a = pfm(os.path.join(a_dir, name))
    _, _, b = pfm(os.path.join(b_dir, name))
    tw, th, t = png(os.path.join(run, cam["file"]))
    assert (tw, th) == (w, h), f"{cam['file']} is {tw}x{th}, the render {w}x{h}"
    r = (psnr(a, t), psnr(b, t), psnr(b, a))
    rows.append(r)
    print(f"{cam['file']} ({cam.get('kind', '?')}, {w}x{h}): PLY {r[0]:.2f} dB, SPZ {r[1]:.2f} dB "
          f"(cost {r[0] - r[1]:+.3f}), SPZ render vs PLY render {r[2]:.2f} dB")
mean = lambda k: sum(r[k] for r in rows) / len(rows)
sp, ss = os.path.getsize(os.path.join(run, "final.ply")), os.path.getsize(spz)
print(f"size: PLY {sp} bytes, SPZ {ss} bytes = {ss / sp:.4f} of the PLY (1/{sp / ss:.1f})")
print(f"PSNR against the training frames over {len(rows)} views: PLY {mean(0):.2f} dB, SPZ {mean(1):.2f} dB, "
      f"cost {mean(0) - mean(1):.3f} dB (largest {max(r[0] - r[1] for r in rows):.3f}); "
      f"SPZ render vs PLY render {mean(2):.2f} dB (min {min(r[2] for r in rows):.2f})")
EOF
