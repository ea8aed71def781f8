#!/usr/bin/env python3
"""Python subscriber for dvrk-sidecar: prints the raw samples of one topic (default the
compensated tip pose in the base frame), every field as published.

A thin user of the `dvrk_sidecar` package in python/ (its ctypes message layouts, the project's
QoS and the three wait strategies), one layer below its crtk-like `Arm` (see arm.py beside this
file). Install the package once with `python3 -m pip install ./python`; from a checkout without
it, this script falls back to the repository's python/ (it then needs only the iceoryx2 package,
`python3 -m pip install iceoryx2==0.10.0`).

Usage:

    python3 examples/python/subscriber.py [--prefix PSM1] [--count 10] [--json]
        [--topic compensated/measured_cp] [--timeout-s 10] [--wait event|spin|predictive]
        [--domain PREFIX [--root /tmp/iox2t/]]

`--wait` chooses how to wait for the next sample, as dvrk_ipc::WaitStrategy does in Rust:
`event` (sleep on the `<prefix>/cycle` event), `spin` (poll, one whole core, no listener) or
`predictive` (learn the publisher's period and phase, sleep until shortly before the next sample
is due, then poll; never later than the event).

It prints the newest sample of each wake-up until `--count` samples are printed (exit 0). Exit 2
if no sample arrives for `--timeout-s` seconds, exit 3 if the publisher goes away (one line on
stderr). `--json` prints one object per line with the message's raw fields (`header.valid` and
`header.flags` as the integers published, `rotation` as 9 row-major numbers), plus `topic` and
`flag_names`. For the project's one JSON shape per message, use
`python3 -m dvrk_sidecar echo PSM1/measured_js --json`, which prints what `dvrk-sidecar echo
--json` prints.
"""

import argparse
import ctypes
import json
import os
import sys
import time

try:
    from dvrk_sidecar import ipc, msg
except ImportError:  # running from a checkout without `pip install ./python`
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "python"))
    from dvrk_sidecar import ipc, msg


def to_dict(value) -> dict:
    """A ctypes structure as plain Python values (nested structures and arrays included)."""
    out = {}
    for name, _ in value._fields_:
        v = getattr(value, name)
        if isinstance(v, ctypes.Structure):
            out[name] = to_dict(v)
        elif isinstance(v, ctypes.Array):
            out[name] = list(v)
        else:
            out[name] = v
    return out


def format_text(sample) -> str:
    h = sample.header
    flags = "|".join(msg.flag_names(h.flags)) or "-"
    head = f"seq={h.seq} valid={h.valid} sample_t_ns={h.sample_t_ns} flags={flags}"
    fmt = lambda xs: "[" + ", ".join(f"{x:.6f}" for x in xs) + "]"  # noqa: E731
    if isinstance(sample, msg.PoseV2):
        return f"{head} position_m={fmt(sample.position_m)} xyzw={fmt(sample.orientation_xyzw)}"
    if isinstance(sample, msg.JointStateV2):
        return f"{head} position={fmt(sample.position)} effort={fmt(sample.effort)}"
    if isinstance(sample, msg.JawStateV1):
        return f"{head} position={sample.position:.6f} effort={sample.effort:.6f}"
    return (
        f"{head} tau_ext_nm={fmt(sample.tau_ext_nm)} delta_rad={fmt(sample.delta_rad)} "
        f"insertion_m={sample.insertion_m:.6f} cycle_period_ns={sample.cycle_period_ns}"
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--prefix", default="PSM1", help="service prefix, the arm's name (default PSM1)")
    parser.add_argument("--count", type=int, default=10, help="samples to print, then exit 0")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument(
        "--topic",
        default="compensated/measured_cp",
        choices=list(msg.TOPICS),
        help="topic under the prefix (default compensated/measured_cp)",
    )
    parser.add_argument(
        "--timeout-s", type=float, default=10.0, help="give up (exit 2) after this long without a sample"
    )
    parser.add_argument("--wait", default="event", choices=ipc.WAIT_STRATEGIES, help="how to wait (default event)")
    parser.add_argument("--domain", help="iceoryx2 domain prefix (default: dvrk_<uid>_, where dvrk-sidecar serve publishes)")
    parser.add_argument("--root", help="iceoryx2 root path of the domain (default $DVRK_SIDECAR_IPC_ROOT or /tmp/dvrk-sidecar-<uid>/)")
    args = parser.parse_args(argv)
    if args.count < 1:
        parser.error("--count must be at least 1")

    node = ipc.create_node("dvrk-sidecar-example", args.domain, args.root)
    # Subscriber first, then the listener (if the strategy has one).
    reader = ipc.Reader(node, args.prefix, args.topic, buffer=ipc.QOS_SUBSCRIBER_MAX_BUFFER_SIZE)
    waiter = ipc.Waiter(node, args.prefix, args.wait)
    service = f"{args.prefix}/{args.topic}"

    printed = 0
    publisher_seen = reader.service.dynamic_config.number_of_publishers > 0
    last_fresh = time.monotonic()
    while printed < args.count:
        # The newest sample of this wake-up (older ones buffered meanwhile are skipped).
        sample = waiter.wait_for(reader.take_newest, time.monotonic_ns() + ipc.NOMINAL_PERIOD_NS * 15)
        if sample is not None:
            publisher_seen = True
            last_fresh = time.monotonic()
            if args.json:
                record = to_dict(sample)
                record["topic"] = service
                record["flag_names"] = msg.flag_names(sample.header.flags)
                print(json.dumps(record), flush=True)
            else:
                print(format_text(sample), flush=True)
            printed += 1
            continue
        # No sample within the deadline. A publisher whose process died still counts until its
        # node is cleaned up (publishers() reaps dead nodes).
        if reader.publishers() > 0:
            publisher_seen = True
        elif publisher_seen:
            print(f"publisher of {service} is gone", file=sys.stderr)
            return 3
        if time.monotonic() - last_fresh > args.timeout_s:
            print(f"no sample on {service} for {args.timeout_s} s", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        sys.exit(130)
