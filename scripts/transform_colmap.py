#!/usr/bin/env python3
"""Writes a COLMAP dataset moved and rescaled by a similarity x' = s x + d, for
checking that results do not depend on where or how big the scene is
(docs/numerics.md).

  scripts/transform_colmap.py SRC DST [--scale S] [--translate X,Y,Z]

SRC holds images/ and sparse/0/ with a text model (cameras.txt, images.txt,
points3D.txt). DST gets sparse/0/ with the transformed model and images/ as a
symbolic link to SRC's. Camera centres C' = s C + d with the rotation kept, so
the world-to-camera translation becomes t' = s t - R d; points X' = s X + d.
Intrinsics do not change. Numbers are written with 17 significant digits, so a
translation of 1e6 keeps the model's own precision.
"""
import argparse
import os
import sys


def quat_to_rot(w, x, y, z):
    # Unit quaternion (COLMAP: w, x, y, z, world-to-camera) to a rotation matrix.
    n = (w * w + x * x + y * y + z * z) ** 0.5
    w, x, y, z = w / n, x / n, y / n, z / n
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]


def fmt(v):
    return repr(float(v))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--translate", default="0,0,0")
    a = ap.parse_args()
    s = a.scale
    d = [float(v) for v in a.translate.split(",")]
    if len(d) != 3 or not s > 0:
        sys.exit("transform_colmap: --translate needs X,Y,Z and --scale must be positive")
    src_model = os.path.join(a.src, "sparse", "0")
    for name in ("cameras.txt", "images.txt", "points3D.txt"):
        if not os.path.isfile(os.path.join(src_model, name)):
            sys.exit(f"transform_colmap: {src_model}/{name} missing (only text models are handled)")
    dst_model = os.path.join(a.dst, "sparse", "0")
    os.makedirs(dst_model, exist_ok=True)
    link = os.path.join(a.dst, "images")
    if not os.path.exists(link):
        os.symlink(os.path.abspath(os.path.join(a.src, "images")), link)

    with open(os.path.join(src_model, "cameras.txt")) as f, open(os.path.join(dst_model, "cameras.txt"), "w") as g:
        g.write(f.read())

    # images.txt: two lines per image; the first carries the pose.
    with open(os.path.join(src_model, "images.txt")) as f:
        lines = f.read().split("\n")
    out, pose_line = [], True
    for line in lines:
        if line.startswith("#"):
            out.append(line)
            continue
        if pose_line and line.strip():
            p = line.split()
            qw, qx, qy, qz, tx, ty, tz = map(float, p[1:8])
            R = quat_to_rot(qw, qx, qy, qz)
            t = [s * [tx, ty, tz][r] - sum(R[r][c] * d[c] for c in range(3)) for r in range(3)]
            p[5:8] = [fmt(v) for v in t]
            out.append(" ".join(p))
            pose_line = False
        else:
            out.append(line)
            pose_line = True
    with open(os.path.join(dst_model, "images.txt"), "w") as g:
        g.write("\n".join(out))

    with open(os.path.join(src_model, "points3D.txt")) as f, open(os.path.join(dst_model, "points3D.txt"), "w") as g:
        for line in f:
            if line.startswith("#") or not line.strip():
                g.write(line)
                continue
            p = line.split()
            p[1:4] = [fmt(s * float(p[1 + c]) + d[c]) for c in range(3)]
            g.write(" ".join(p) + "\n")


if __name__ == "__main__":
    main()
