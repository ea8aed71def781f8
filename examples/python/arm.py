#!/usr/bin/env python3
"""Python example for dvrk-sidecar: the crtk-like Arm API, printing the compensated tip pose of every cycle.

A small user of the `dvrk_sidecar` package (python/ in this repository), which holds the message
layouts, the wait strategies and the crtk-like API. Install it once:

    python3 -m pip install ./python

(from a checkout without installing, this script falls back to the repository's python/).

Usage:

    python3 examples/python/arm.py [--arm PSM1] [--count 10] [--json]
        [--frame local|base] [--wait event|spin|predictive] [--timeout-s 10]
        [--domain PREFIX [--root /tmp/iox2t/]]

For each new cycle (`Arm.wait_for_cycle`) it reads `compensated/local/measured_cp` (RCM frame)
or, with `--frame base`, `compensated/measured_cp` as a 4x4 numpy array and prints it. An invalid
sample is printed as such (the client raises `InvalidSample` for it), not as a pose. Exit 0 after
`--count` cycles, 2 if no cycle comes for `--timeout-s` seconds. `--json` prints one object per
line: `{"seq", "sample_realtime_ns", "valid", "flags", "matrix": [[4], [4], [4], [4]]}`.
"""

import argparse
import json
import os
import sys

try:
    import dvrk_sidecar
except ImportError:  # running from a checkout without `pip install ./python`
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "python"))
    import dvrk_sidecar

from dvrk_sidecar import Arm, InvalidSample


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--arm", default="PSM1", help="the arm's name, the service prefix (default PSM1)")
    parser.add_argument("--count", type=int, default=10, help="cycles to print, then exit 0")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument("--frame", default="local", choices=("local", "base"), help="RCM (local) or base frame")
    parser.add_argument("--wait", default="event", choices=dvrk_sidecar.WAIT_STRATEGIES, help="how to wait")
    parser.add_argument("--timeout-s", type=float, default=10.0, help="exit 2 after this long without a cycle")
    parser.add_argument("--domain", help="iceoryx2 domain prefix (default: dvrk_<uid>_, where dvrk-sidecar serve publishes)")
    parser.add_argument("--root", help="iceoryx2 root path of the domain (default $DVRK_SIDECAR_IPC_ROOT or /tmp/dvrk-sidecar-<uid>/)")
    args = parser.parse_args(argv)
    if args.count < 1:
        parser.error("--count must be at least 1")

    with Arm(args.arm, wait=args.wait, domain=args.domain, root=args.root) as arm:
        read = arm.compensated.local.measured_cp if args.frame == "local" else arm.compensated.measured_cp
        for _ in range(args.count):
            if arm.wait_for_cycle(timeout=args.timeout_s) is None:
                print(f"no cycle of {args.arm} for {args.timeout_s} s", file=sys.stderr)
                return 2
            try:
                matrix, header = read(extra=True)
            except InvalidSample as e:
                matrix, header = None, e.header
            if args.json:
                record = {
                    "seq": header.seq,
                    "sample_realtime_ns": header.sample_realtime_ns,
                    "valid": header.valid,
                    "flags": list(header.flags),
                    "matrix": None if matrix is None else matrix.tolist(),
                }
                print(json.dumps(record), flush=True)
            elif matrix is None:
                print(f"seq {header.seq} invalid: {' '.join(header.flags)}", flush=True)
            else:
                p = matrix[:3, 3]
                print(
                    f"seq {header.seq} stamp {header.stamp:.6f} position_m "
                    f"[{p[0]:+.6f}, {p[1]:+.6f}, {p[2]:+.6f}] flags [{' '.join(header.flags)}]",
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        sys.exit(130)
