#!/usr/bin/env python3
"""Compare two builds of a Google Benchmark program on a noisy machine.

    scripts/bench_ab.py BEFORE AFTER [--filter REGEX] [--rounds N] [--counters a,b,...]

e.g. keep a copy of bench_render before a change, rebuild, then

    scripts/bench_ab.py /tmp/bench_render_before build-bench/bench/bench_render \\
        --filter 'BM_(Forward|Backward)Ball' --rounds 8

Runs BEFORE and AFTER alternately, one pass of each benchmark per run, ROUNDS
times, so that drift in the machine's speed (a shared machine can vary 2x
between passes) falls on both alike. Prints, per benchmark and counter, the
best pass and the median of each build and the ratio of the best passes. Only
the ratios within one run compare; compare nothing with another run's figures.
"""
import argparse
import json
import statistics
import subprocess
import sys
from collections import defaultdict

DEFAULT_COUNTERS = "real_time,project_ns_g,sort_ns_g,bin_ns_g,gauss_ns_g,pass_ns_contrib,fwd_ns_contrib,bwd_ns_contrib,ms_per_step"


def run_once(program, flt):
    try:
        out = subprocess.run([program, "--benchmark_filter=" + flt, "--benchmark_format=json"],
                             check=True, capture_output=True, text=True).stdout
    except FileNotFoundError:
        sys.exit(f"bench_ab: no program at {program}")
    except subprocess.CalledProcessError as e:
        sys.exit(f"bench_ab: {program} failed (exit status {e.returncode}): {e.stderr.strip()[-500:]}")
    return json.loads(out)["benchmarks"]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("--filter", default=".", help="--benchmark_filter for both programs")
    ap.add_argument("--rounds", type=int, default=8)
    ap.add_argument("--counters", default=DEFAULT_COUNTERS, help="comma-separated fields to report (those present)")
    a = ap.parse_args()
    if a.rounds < 1:
        sys.exit("bench_ab: --rounds must be at least 1")
    fields = [c for c in a.counters.split(",") if c]
    seen = {"before": defaultdict(lambda: defaultdict(list)), "after": defaultdict(lambda: defaultdict(list))}
    for r in range(a.rounds):
        for tag, program in (("before", a.before), ("after", a.after)):
            for b in run_once(program, a.filter):
                if b.get("run_type", "iteration") != "iteration":
                    continue
                name = b["run_name"].split("/min_time")[0]
                for f in fields:
                    if isinstance(b.get(f), (int, float)):
                        seen[tag][name][f].append(float(b[f]))
        print(f"round {r + 1} of {a.rounds} done", file=sys.stderr)
    names = list(seen["before"].keys())
    if not names:
        sys.exit("bench_ab: no benchmark matched the filter")
    print(f"{a.rounds} alternated rounds; best pass (median) per build; after / before of the best passes")
    for name in names:
        print(name)
        for f in fields:
            b, c = seen["before"][name].get(f), seen["after"].get(name, {}).get(f)
            if not b or not c:
                continue
            ratio = min(c) / min(b) if min(b) > 0 else float("nan")
            print(f"  {f:18s} {min(b):10.2f} ({statistics.median(b):.2f})  ->  {min(c):10.2f} ({statistics.median(c):.2f})"
                  f"   x{ratio:.3f}")


if __name__ == "__main__":
    main()
