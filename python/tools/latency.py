#!/usr/bin/env python3
"""Latency of the Python client per wait strategy, against a running `dvrk-sidecar serve`.

    python3 python/tools/latency.py --arm PSM1 --seconds 10 [--wait event,spin,predictive]

For each strategy it calls `Arm.wait_for_cycle()` in a loop and records, per returned cycle,
`time.monotonic_ns()` at the return minus the cycle's `publish_t_ns` (both CLOCK_MONOTONIC):
the time from the sidecar's publish to the Python caller holding the header. Also counts the
cycles it did not see (seq gaps) and the process CPU time spent. Prints one JSON object per
strategy. Measured numbers go to benches/README.md with the date and machine.
"""

import argparse
import json
import sys
import time

from dvrk_sidecar import Arm


def pct(xs, q):
    return xs[min(len(xs) - 1, int(q * len(xs)))]


def run(args, wait):
    with Arm(args.arm, wait=wait, domain=args.domain, root=args.root, timeout=2.0) as arm:
        # Let the predictor learn and the first cycles pass before measuring.
        for _ in range(200):
            if arm.wait_for_cycle() is None:
                raise SystemExit(f"no cycle of {args.arm}: is serve running?")
        lat = []
        missed = 0
        last = None
        cpu0 = time.process_time()
        end = time.monotonic_ns() + int(args.seconds * 1e9)
        while time.monotonic_ns() < end:
            h = arm.wait_for_cycle()
            now = time.monotonic_ns()
            if h is None:
                raise SystemExit("cycles stopped")
            lat.append(now - h.publish_t_ns)
            if last is not None and h.seq > last + 1:
                missed += h.seq - last - 1
            last = h.seq
        cpu = time.process_time() - cpu0
    lat.sort()
    return {
        "wait": wait,
        "cycles": len(lat),
        "missed_cycles": missed,
        "p50_us": pct(lat, 0.5) / 1e3,
        "p90_us": pct(lat, 0.9) / 1e3,
        "p99_us": pct(lat, 0.99) / 1e3,
        "max_us": lat[-1] / 1e3,
        "cpu_percent": 100.0 * cpu / args.seconds,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--arm", default="PSM1")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--wait", default="event,spin,predictive")
    parser.add_argument("--domain")
    parser.add_argument("--root")
    args = parser.parse_args()
    for wait in args.wait.split(","):
        print(json.dumps(run(args, wait)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
