"""Drives the installed dvrk_sidecar.Arm and prints what it got as JSON lines, for
tests/python_client.rs to compare with `dvrk-sidecar echo --json` of the same seq.

    python3 arm_probe.py cycles ARM WAIT COUNT [--domain D --root R]
        one line per cycle: wait_for_cycle's header, then measured_js, jaw/measured_js,
        compensated/local/measured_cp and compensated/measured_cp read with extra=True
    python3 arm_probe.py invalid ARM [--domain D --root R]
        reads measured_js from a publisher of invalid samples; prints the InvalidSample
    python3 arm_probe.py silent ARM [--domain D --root R]
        reads measured_js where nobody publishes; prints the NoSample
    python3 arm_probe.py gil ARM [--domain D --root R]
        where nobody publishes: counts how far another Python thread gets while this one waits
        0.3 s in measured_js; prints {"counted": n, "waited_s": s}

--backend native|pure chooses the Arm's client (default: the package's BACKEND); with native,
`cycles` also checks that the arrays are views of one array per message and the dVRK 2.4
getters (stamped=True), and `invalid` that stamped=True returns a zero timestamp.

Exit 0 when the client behaved as documented, 1 with a message on stderr otherwise.
"""

import argparse
import dataclasses
import json
import sys

import numpy

import dvrk_sidecar
from dvrk_sidecar import Arm, InvalidSample, NoSample


def header(h):
    d = dataclasses.asdict(h)
    d["flags"] = list(d["flags"])
    return d


def cycles(arm, count):
    last = None
    for _ in range(count):
        cycle = arm.wait_for_cycle(timeout=5.0)
        if cycle is None:
            print("wait_for_cycle timed out", file=sys.stderr)
            return 1
        if last is not None and cycle.seq <= last:
            print(f"wait_for_cycle went from seq {last} to {cycle.seq}", file=sys.stderr)
            return 1
        last = cycle.seq
        p, v, e, hj = arm.measured_js(extra=True)
        jp, jv, je, hjaw = arm.jaw.measured_js(extra=True)
        local, hl = arm.compensated.local.measured_cp(extra=True)
        base, hb = arm.compensated.measured_cp(extra=True)
        for name, a, n in (("position", p, 6), ("velocity", v, 6), ("effort", e, 6), ("jaw", jp, 1)):
            if not isinstance(a, numpy.ndarray) or a.shape != (n,):
                print(f"{name} is {type(a).__name__} {getattr(a, 'shape', '')}", file=sys.stderr)
                return 1
        for name, m in (("local", local), ("base", base)):
            if not isinstance(m, numpy.ndarray) or m.shape != (4, 4):
                print(f"{name} measured_cp is not a 4x4 array", file=sys.stderr)
                return 1
        for name, a in (("position", p), ("velocity", v), ("jaw", jp)):
            if a.dtype != numpy.float64:
                print(f"{name} has dtype {a.dtype}", file=sys.stderr)
                return 1
            if arm.backend == "native" and a.base is None:
                print(f"{name} is a copy, not a view of the message", file=sys.stderr)
                return 1
        sp, sv, se, stamp = arm.measured_js(stamped=True)
        sh = arm.measured_js(extra=True)[-1]
        if sp.shape != (6,) or not isinstance(stamp, float) or stamp <= 0.0 or stamp + 1.0 < sh.stamp:
            print(f"measured_js(stamped=True) gave stamp {stamp!r} (header stamp {sh.stamp})", file=sys.stderr)
            return 1
        tip, tstamp = arm.compensated.local.measured_cp(stamped=True)
        if tip.shape != (4, 4) or tstamp <= 0.0:
            print(f"measured_cp(stamped=True) gave {tip.shape}, {tstamp!r}", file=sys.stderr)
            return 1
        snapshot = arm.read_cycle(timeout=5.0)
        if snapshot is None:
            print("read_cycle timed out", file=sys.stderr)
            return 1
        snap_js = snapshot.measured_js(extra=True)
        snap_local = snapshot.compensated.local.measured_cp(extra=True)
        if {snap_js[-1].seq, snap_local[-1].seq, snapshot.seq} != {snapshot.seq}:
            print(f"read_cycle mixed cycles: {snap_js[-1].seq}, {snap_local[-1].seq}", file=sys.stderr)
            return 1
        record = {
            "wait": arm.wait_strategy,
            "backend": arm.backend,
            "cycle": header(cycle),
            "measured_js": {"header": header(hj), "position": p.tolist(), "velocity": v.tolist(), "effort": e.tolist()},
            "jaw/measured_js": {"header": header(hjaw), "position": jp.tolist(), "velocity": jv.tolist(), "effort": je.tolist()},
            "compensated/local/measured_cp": {"header": header(hl), "matrix": local.tolist()},
            "compensated/measured_cp": {"header": header(hb), "matrix": base.tolist()},
            "stamp": hj.stamp,
            "read_cycle": {
                "seq": snapshot.seq,
                "position": snap_js[0].tolist(),
                "matrix": snap_local[0].tolist(),
            },
        }
        print(json.dumps(record), flush=True)
    return 0


def invalid(arm):
    p, v, e, stamp = arm.measured_js(wait=10.0, stamped=True)
    if stamp != 0.0 or p.shape != (6,):
        print(f"stamped=True on an invalid sample gave stamp {stamp!r}", file=sys.stderr)
        return 1
    try:
        value = arm.measured_js(wait=10.0)
    except InvalidSample as e:
        pos = e.value[0]
        print(json.dumps({"error": str(e), "header": header(e.header), "position": pos.tolist()}), flush=True)
        return 0
    print(f"an invalid sample was returned: {value}", file=sys.stderr)
    return 1


def silent(arm):
    try:
        arm.measured_js(age=0.0, wait=0.2)
    except NoSample as e:
        if not isinstance(e, TimeoutError):
            print("NoSample is not a TimeoutError", file=sys.stderr)
            return 1
        print(json.dumps({"error": str(e)}), flush=True)
        return 0
    print("measured_js returned with nobody publishing", file=sys.stderr)
    return 1


def gil(arm):
    import threading
    import time

    counted = [0]
    stop = threading.Event()

    def count():
        while not stop.is_set():
            counted[0] += 1

    t = threading.Thread(target=count)
    t.start()
    time.sleep(0.05)  # the thread runs
    before = counted[0]
    t0 = time.monotonic()
    try:
        arm.measured_js(age=0.0, wait=0.3)
    except NoSample:
        pass
    waited = time.monotonic() - t0
    during = counted[0] - before
    stop.set()
    t.join()
    print(json.dumps({"counted": during, "waited_s": waited, "backend": arm.backend}), flush=True)
    return 0


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("mode", choices=("cycles", "invalid", "silent", "gil"))
    parser.add_argument("arm")
    parser.add_argument("wait", nargs="?", default="event")
    parser.add_argument("count", nargs="?", type=int, default=20)
    parser.add_argument("--domain")
    parser.add_argument("--root")
    parser.add_argument("--backend")
    args = parser.parse_args()
    print(f"dvrk_sidecar from {dvrk_sidecar.__file__}", file=sys.stderr)
    with Arm(args.arm, wait=args.wait, domain=args.domain, root=args.root, timeout=5.0,
             backend=args.backend) as arm:
        if args.mode == "cycles":
            return cycles(arm, args.count)
        if args.mode == "invalid":
            return invalid(arm)
        if args.mode == "gil":
            return gil(arm)
        return silent(arm)


if __name__ == "__main__":
    sys.exit(main())
