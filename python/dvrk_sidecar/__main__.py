"""Command line: `python -m dvrk_sidecar echo SERVICE [--json] [--count N] [--wait W]` and
`python -m dvrk_sidecar layout`.

echo prints every sample of one service, oldest first, like `dvrk-sidecar echo`; with --json one
object per line in the same shape (`{"topic", "header": {...}, ...body}`). Exit status: 0 after
--count samples, 2 when no sample came for --timeout-s seconds, 1 on a bad argument or an
iceoryx2 failure, 130 on Ctrl-C.

layout prints the ctypes layouts (type name, size, alignment, every field's offset, size and
type) as JSON, for the check against the Rust types.
"""

import argparse
import json
import sys
import time

from . import ipc, msg

_SILENCE_REPORT_NS = 1_000_000_000


def _text(service: str, m) -> str:
    h = m.header
    flags = " ".join(msg.flag_names(h.flags))
    head = f"{service} seq {h.seq} t {h.sample_t_ns * 1e-9:.6f} s valid {int(h.valid != 0)} flags [{flags}]"
    body = msg.body_json(m)

    def fmt(xs):
        return "[" + ", ".join(f"{x:+.6f}" for x in xs) + "]"

    if isinstance(m, (msg.JointStateV2, msg.JawStateV1)):
        return f"{head}\n  position {fmt(body['position'])}\n  velocity {fmt(body['velocity'])}\n  effort   {fmt(body['effort'])}"
    if isinstance(m, msg.PoseV2):
        rows = "; ".join(", ".join(f"{x:+.5f}" for x in r) for r in body["rotation"])
        return f"{head}\n  position_m {fmt(body['position_m'])}\n  rotation   [{rows}]"
    return f"{head}\n  " + "  ".join(f"{k} {v}" for k, v in body.items())


def echo(args) -> int:
    try:
        prefix, topic = msg.split_service(args.service, args.prefix)
        ipc.check_prefix(prefix)
        service = f"{prefix}/{topic}"
        node = ipc.create_node("dvrk-sidecar-py-echo", args.domain, args.root)
        reader = ipc.Reader(node, prefix, topic, buffer=ipc.QOS_SUBSCRIBER_MAX_BUFFER_SIZE)
        waiter = ipc.Waiter(node, prefix, args.wait)
    except (ValueError, ipc.DvrkSidecarError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    except Exception as e:  # iceoryx2's own errors (e.g. incompatible types)
        print(f"error: opening {args.service}: {type(e).__name__}: {e}", file=sys.stderr)
        return 1

    limit = args.count if args.count is not None else float("inf")
    printed = 0
    batch = []

    def poll():
        newest = None
        while True:
            m = reader.take()
            if m is None:
                return newest
            batch.append(m)
            newest = m

    last_fresh = time.monotonic_ns()
    gone = False
    seen_publisher = False
    out = sys.stdout
    while printed < limit:
        until = time.monotonic_ns() + _SILENCE_REPORT_NS
        if args.timeout_s is not None:
            until = min(until, last_fresh + int(args.timeout_s * 1e9))
        got = waiter.wait_for(poll, until)
        if got is not None:
            for m in batch:
                if printed >= limit:
                    break
                if args.json:
                    line = json.dumps(msg.to_json(service, m), sort_keys=True, separators=(",", ":"))
                else:
                    line = _text(service, m)
                out.write(line + "\n")
                printed += 1
            batch.clear()
            out.flush()
            last_fresh = time.monotonic_ns()
            seen_publisher = True
            if gone:
                print(f"a publisher of {service} is back", file=sys.stderr)
                gone = False
            continue
        # A second without a sample: say once that the publisher went away, keep waiting
        # (like `ros2 topic echo`) until --timeout-s.
        publishers = reader.publishers()
        if publishers > 0:
            seen_publisher = True
        elif seen_publisher and not gone:
            print(f"publisher of {service} is gone; waiting for a new one", file=sys.stderr)
            gone = True
        waited = (time.monotonic_ns() - last_fresh) / 1e9
        if args.timeout_s is not None and waited >= args.timeout_s:
            print(f"error: {reader.no_sample(waited)}", file=sys.stderr)
            return 2
    return 0


def layout(_args) -> int:
    print(json.dumps(msg.layouts(), indent=1))
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dvrk_sidecar", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    e = sub.add_parser("echo", help="print samples of one service, like `dvrk-sidecar echo`")
    e.add_argument(
        "service",
        help="service as the dVRK names the topic (PSM1/measured_js, /PSM1/local/measured_cp), "
        "or a bare topic under --prefix",
    )
    e.add_argument("--prefix", default="PSM1", help="prefix of a bare topic name (default PSM1)")
    e.add_argument("--count", type=int, help="stop after this many samples (default: until Ctrl-C)")
    e.add_argument("--json", action="store_true", help="one JSON object per line")
    e.add_argument("--wait", default="event", choices=ipc.WAIT_STRATEGIES, help="how to wait (default event)")
    e.add_argument("--timeout-s", type=float, help="exit 2 after this long without a sample (default: wait)")
    e.add_argument("--domain", help="iceoryx2 domain prefix (default: dvrk_<uid>_, where dvrk-sidecar serve publishes)")
    e.add_argument("--root", help="iceoryx2 root path of the domain (default $DVRK_SIDECAR_IPC_ROOT or /tmp/dvrk-sidecar-<uid>/)")
    e.set_defaults(run=echo)
    lay = sub.add_parser("layout", help="print the message layouts as JSON")
    lay.set_defaults(run=layout)
    args = parser.parse_args(argv)
    if getattr(args, "count", None) is not None and args.count < 1:
        parser.error(f"--count {args.count}: must be at least 1")
    if getattr(args, "timeout_s", None) is not None and not args.timeout_s > 0:
        parser.error(f"--timeout-s {args.timeout_s}: must be > 0")
    try:
        return args.run(args)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
