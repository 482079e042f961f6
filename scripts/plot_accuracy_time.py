#!/usr/bin/python3
"""Holdout PSNR against training seconds from reconstruct's metrics.json files.

    scripts/plot_accuracy_time.py --out curve.png [--table table.md] \
        LABEL=out/curves/static/metrics.json LABEL2=...

Each metrics.json must hold "curve" (reconstruct --eval-every N). The table gives
each curve's holdout PSNR at 1, 3 and 10 minutes: the last evaluation at or
before that time, leaving out evaluations taken right after an opacity reset
(more than 5 dB below both neighbours: a transient the scene recovers from within
~100 iterations; they stay in the plot); "-" when there was none yet; "(ended)"
when the run had finished its iteration budget before that time, so the figure
is its final one. OpenSplat 1.1.5's figures on the static split (issue text, same machine
kind) are drawn as reference points. Uses Debian's python3-matplotlib.
"""
import argparse
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

OPENSPLAT_STATIC = [(60, 24.5), (180, 24.3), (600, 28.5), (960, 29.0), (1920, 32.2)]
MARKS = [60, 180, 600]


def load_curve(path):
    with open(path) as f:
        m = json.load(f)
    curve = m.get("curve")
    if not curve:
        sys.exit(f"{path}: no \"curve\" (run reconstruct with --eval-every N)")
    pts = [(float(c["seconds"]), float(c["holdout_psnr"])) for c in curve]
    return pts, m


def reset_transients(pts):
    """Indices of evaluations taken right after an opacity reset: more than 5 dB
    below both neighbours (the scene recovers within the next ~100 iterations)."""
    out = set()
    for i in range(1, len(pts) - 1):
        if pts[i][1] < pts[i - 1][1] - 5 and pts[i][1] < pts[i + 1][1] - 5:
            out.add(i)
    return out


def at_time(pts, t):
    """(PSNR of the last evaluation at or before t that is not a reset transient,
    True when the run had ended by then)."""
    skip = reset_transients(pts)
    best = None
    for i, (s, p) in enumerate(pts):
        if s <= t * 1.02 and i not in skip:  # an evaluation a few seconds late still counts as "at" t
            best = p
    return best, pts[-1][0] < t * 0.98


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--table")
    ap.add_argument("--title", default="cool_teddy, 512x512, holdout every 8th frame")
    ap.add_argument("runs", nargs="+", help="LABEL=path/to/metrics.json")
    a = ap.parse_args()

    fig, ax = plt.subplots(figsize=(7, 4.2), dpi=120)
    rows = []
    for run in a.runs:
        if "=" not in run:
            sys.exit(f"expected LABEL=metrics.json, got {run!r}")
        label, path = run.split("=", 1)
        pts, m = load_curve(path)
        ax.plot([s / 60 for s, _ in pts], [p for _, p in pts], label=label, lw=1.5)
        rows.append((label, [at_time(pts, t) for t in MARKS], m))
    ax.plot([t / 60 for t, _ in OPENSPLAT_STATIC], [p for _, p in OPENSPLAT_STATIC], "k^--", lw=0.8, ms=5,
            label="OpenSplat 1.1.5 CPU, static (reference)")
    ax.axhline(32.2, color="k", ls=":", lw=0.8)
    ax.text(0.2, 32.35, "OpenSplat's best: 32.2 dB after 32 min", fontsize=7)
    for t in MARKS:
        ax.axvline(t / 60, color="0.85", lw=0.8, zorder=0)
    ax.set_xlabel("training wall-clock minutes (2 cores; dips: evaluations right after an opacity reset)")
    ax.set_ylabel("holdout PSNR (dB)")
    ax.set_xlim(0, 11)
    ax.set_title(a.title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    tmp = a.out + ".tmp.png"
    fig.savefig(tmp)
    os.replace(tmp, a.out)

    if a.table:
        lines = ["| run | 1 min | 3 min | 10 min | iterations | Gaussians | final holdout PSNR / SSIM |",
                 "|---|---|---|---|---|---|---|"]
        for label, vals, m in rows:
            cells = ["-" if v is None else f"{v:.2f}" + (" (ended)" if ended else "") for v, ended in vals]
            final = f"{m.get('holdout_psnr', float('nan')):.2f} / {m.get('holdout_ssim', float('nan')):.3f}"
            if "holdout_psnr_baked" in m:
                final += f" (MedianGS bake {m['holdout_psnr_baked']:.2f})"
            lines.append(f"| {label} | " + " | ".join(cells) + f" | {m.get('iterations')} | {m.get('gaussians')} | {final} |")
        text = "\n".join(lines) + "\n"
        with open(a.table + ".tmp", "w") as f:
            f.write(text)
        os.replace(a.table + ".tmp", a.table)
        print(text, end="")


if __name__ == "__main__":
    main()
