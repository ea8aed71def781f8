#!/usr/bin/env python3
"""Python subscriber for dvrk-sidecar: prints samples of one topic (default the compensated tip pose).

Requires the iceoryx2 Python package of the same version as the sidecar's crate:

    python3 -m pip install iceoryx2==0.10.0

Usage:

    python3 examples/python/subscriber.py [--prefix dvrk/PSM1] [--count 10] [--json]
        [--topic compensated/measured_cp] [--timeout-s 10]
        [--domain PREFIX [--root /tmp/iox2t/]]

It sleeps in an iceoryx2 WaitSet on the `<prefix>/cycle` event (deadline: 3 nominal periods),
drains the event and every buffered sample, and prints the newest sample of each wake-up, until
`--count` samples are printed (exit 0). Exit 2 if no sample arrives for `--timeout-s` seconds,
exit 3 if the publisher goes away. `--json` prints one JSON object per line.

The ctypes structures mirror crates/dvrk-ipc/src/msg.rs (and include/dvrk_ipc.h) byte for byte,
and declare the same iceoryx2 type names (`dvrk::PoseV1`, ...) through the `type_name()`
classmethod that the iceoryx2 package looks for. The services are opened (or created) with the
project's QoS, so this script may start before or after the sidecar.
"""

import argparse
import ctypes
import json
import sys
import time

import iceoryx2 as iox2

NUM_JOINTS = 7
JOINT_NAMES = ("yaw", "pitch", "insertion", "roll", "wrist_pitch", "wrist_yaw", "jaw")

# QoS: the same values as dvrk_ipc::qos (Rust) and DVRK_IPC_QOS_* (C).
QOS_MAX_PUBLISHERS = 1
QOS_MAX_SUBSCRIBERS = 32
QOS_SUBSCRIBER_MAX_BUFFER_SIZE = 256
QOS_SUBSCRIBER_MAX_BORROWED_SAMPLES = 2
QOS_HISTORY_SIZE = 1
QOS_ENABLE_SAFE_OVERFLOW = True
QOS_MAX_NODES = 36
QOS_EVENT_MAX_NOTIFIERS = 1
QOS_EVENT_MAX_LISTENERS = 32

DEADLINE_PERIODS = 3
NOMINAL_PERIOD_NS = 666_667  # 1500 Hz

# Header.flags bits (dvrk_ipc::flags), in bit order.
FLAG_NAMES = (
    "BOARD_TIMEOUT",
    "BOARD_ERROR",
    "WATCHDOG_TIMEOUT",
    "POWER_OFF",
    "ENCODER_ERROR",
    "AMP_FAULT",
    "INSERTION_CLAMPED",
    "CORRECTION_ACTIVE_J1",
    "CORRECTION_ACTIVE_J2",
    "SIMULATED",
    "OVERRUN",
    "IMPLAUSIBLE",
    "NO_SOURCE",
    "HELD",
)

f64 = ctypes.c_double
u64 = ctypes.c_uint64
u32 = ctypes.c_uint32


class Header(ctypes.Structure):
    """Common header, 40 bytes."""

    _fields_ = [
        ("seq", u64),
        ("sample_t_ns", u64),
        ("board_timestamp", u64),
        ("publish_t_ns", u64),
        ("valid", u32),
        ("flags", u32),
    ]

    @classmethod
    def type_name(cls) -> str:
        return "dvrk::HeaderV1"


class JointStateV1(ctypes.Structure):
    """measured_js and compensated/measured_js, 208 bytes."""

    _fields_ = [
        ("header", Header),
        ("position", f64 * NUM_JOINTS),
        ("velocity", f64 * NUM_JOINTS),
        ("effort", f64 * NUM_JOINTS),
    ]

    @classmethod
    def type_name(cls) -> str:
        return "dvrk::JointStateV1"


class PoseV1(ctypes.Structure):
    """measured_cp and compensated/measured_cp (RCM frame), 168 bytes; rotation row-major."""

    _fields_ = [
        ("header", Header),
        ("position_m", f64 * 3),
        ("orientation_xyzw", f64 * 4),
        ("rotation", f64 * 9),
    ]

    @classmethod
    def type_name(cls) -> str:
        return "dvrk::PoseV1"


class CompensationStatusV2(ctypes.Structure):
    """compensated/status, 168 bytes."""

    _fields_ = [
        ("header", Header),
        ("tau_ext_nm", f64 * 2),
        ("delta_rad", f64 * 2),
        ("insertion_m", f64),
        ("cycle_period_ns", u64),
        ("cycle_duration_ns", u64),
        ("cycles_total", u64),
        ("read_failures_total", u64),
        ("overruns_total", u64),
        ("consecutive_read_failures", u32),
        ("_reserved", u32),
        ("tau_margin_nm", f64 * 2),
        ("held_sample_age_ns", u64),
        ("publish_late_ns", u64),
        ("implausible_total", u64),
    ]

    @classmethod
    def type_name(cls) -> str:
        return "dvrk::CompensationStatusV2"


# Layout checks: the same sizes and offsets as the Rust const assertions.
for _t, _size in ((Header, 40), (JointStateV1, 208), (PoseV1, 168), (CompensationStatusV2, 168)):
    assert ctypes.sizeof(_t) == _size, (_t.__name__, ctypes.sizeof(_t))
    assert ctypes.alignment(_t) == 8, _t.__name__
assert Header.flags.offset == 36
assert JointStateV1.effort.offset == 152
assert PoseV1.rotation.offset == 96
assert CompensationStatusV2.consecutive_read_failures.offset == 120
assert CompensationStatusV2.implausible_total.offset == 160

TOPICS = {
    "measured_js": JointStateV1,
    "measured_cp": PoseV1,
    "compensated/measured_js": JointStateV1,
    "compensated/measured_cp": PoseV1,
    "compensated/status": CompensationStatusV2,
}


def flag_names(flags: int) -> list:
    return [name for bit, name in enumerate(FLAG_NAMES) if flags & (1 << bit)]


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


def format_text(topic: str, sample) -> str:
    h = sample.header
    flags = "|".join(flag_names(h.flags)) or "-"
    head = f"seq={h.seq} valid={h.valid} sample_t_ns={h.sample_t_ns} flags={flags}"
    fmt = lambda xs: "[" + ", ".join(f"{x:.6f}" for x in xs) + "]"  # noqa: E731
    if isinstance(sample, PoseV1):
        return f"{head} position_m={fmt(sample.position_m)} xyzw={fmt(sample.orientation_xyzw)}"
    if isinstance(sample, JointStateV1):
        return f"{head} position={fmt(sample.position)} effort={fmt(sample.effort)}"
    return (
        f"{head} tau_ext_nm={fmt(sample.tau_ext_nm)} delta_rad={fmt(sample.delta_rad)} "
        f"insertion_m={sample.insertion_m:.6f} cycle_period_ns={sample.cycle_period_ns}"
    )


def make_config(domain, root):
    """iceoryx2's built-in defaults (no config file lookup), optionally an isolated domain."""
    cfg = iox2.config.default()
    if domain is not None:
        cfg.global_cfg.prefix = iox2.FileName.new(domain)
    if root is not None:
        cfg.global_cfg.root_path = iox2.Path.new(root if root.endswith("/") else root + "/")
    return cfg


def open_services(node, prefix: str, topic: str):
    """Opens or creates the topic and the cycle event with the project's QoS."""
    payload = TOPICS[topic]
    service = (
        node.service_builder(iox2.ServiceName.new(f"{prefix}/{topic}"))
        .publish_subscribe(payload)
        .max_publishers(QOS_MAX_PUBLISHERS)
        .max_subscribers(QOS_MAX_SUBSCRIBERS)
        .max_nodes(QOS_MAX_NODES)
        .subscriber_max_buffer_size(QOS_SUBSCRIBER_MAX_BUFFER_SIZE)
        .subscriber_max_borrowed_samples(QOS_SUBSCRIBER_MAX_BORROWED_SAMPLES)
        .history_size(QOS_HISTORY_SIZE)
        .enable_safe_overflow(QOS_ENABLE_SAFE_OVERFLOW)
        .open_or_create()
    )
    event = (
        node.service_builder(iox2.ServiceName.new(f"{prefix}/cycle"))
        .event()
        .max_notifiers(QOS_EVENT_MAX_NOTIFIERS)
        .max_listeners(QOS_EVENT_MAX_LISTENERS)
        .max_nodes(QOS_MAX_NODES)
        .open_or_create()
    )
    return service, event


def drain(subscriber, payload):
    """Takes every buffered sample; returns the newest as a copy (or None)."""
    newest = None
    while True:
        sample = subscriber.receive()
        if sample is None:
            return newest
        newest = payload.from_buffer_copy(sample.payload().contents)
        sample.delete()  # release the shared-memory slot now, not at garbage collection


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--prefix", default="dvrk/PSM1", help="service prefix (default dvrk/PSM1)")
    parser.add_argument("--count", type=int, default=10, help="samples to print, then exit 0")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument(
        "--topic",
        default="compensated/measured_cp",
        choices=sorted(TOPICS),
        help="topic under the prefix (default compensated/measured_cp)",
    )
    parser.add_argument(
        "--timeout-s", type=float, default=10.0, help="give up (exit 2) after this long without a sample"
    )
    parser.add_argument("--domain", help="iceoryx2 domain prefix (default: iceoryx2's iox2_)")
    parser.add_argument("--root", help="iceoryx2 root path of the domain (default /tmp/iceoryx2/)")
    args = parser.parse_args(argv)
    if args.count < 1:
        parser.error("--count must be at least 1")

    iox2.set_log_level_from_env_or(iox2.LogLevel.Warn)
    payload = TOPICS[args.topic]
    node = (
        iox2.NodeBuilder.new()
        .config(make_config(args.domain, args.root))
        .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
        .create(iox2.ServiceType.Ipc)
    )
    service, event = open_services(node, args.prefix, args.topic)
    subscriber = service.subscriber_builder().create()
    listener = event.listener_builder().create()
    waitset = (
        iox2.WaitSetBuilder.new()
        .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
        .create(iox2.ServiceType.Ipc)
    )
    guard = waitset.attach_deadline(
        listener, iox2.Duration.from_nanos(DEADLINE_PERIODS * NOMINAL_PERIOD_NS)
    )

    printed = 0
    publisher_seen = service.dynamic_config.number_of_publishers > 0
    last_fresh = time.monotonic()
    while printed < args.count:
        (triggers, result) = waitset.wait_and_process()
        for attachment in triggers:
            if attachment.has_event_from(guard):
                listener.try_wait()  # level-triggered: consume the notifications
        if result in (iox2.WaitSetRunResult.Interrupt, iox2.WaitSetRunResult.TerminationRequest):
            return 130
        sample = drain(subscriber, payload)
        if sample is not None:
            publisher_seen = True
            last_fresh = time.monotonic()
            if args.json:
                record = to_dict(sample)
                record["topic"] = f"{args.prefix}/{args.topic}"
                record["flag_names"] = flag_names(sample.header.flags)
                print(json.dumps(record), flush=True)
            else:
                print(format_text(args.topic, sample), flush=True)
            printed += 1
            continue
        # No sample: deadline missed, or an event for a cycle already drained. A publisher whose
        # process died still counts until its node is cleaned up.
        service.try_cleanup_dead_nodes()
        if service.dynamic_config.number_of_publishers > 0:
            publisher_seen = True
        elif publisher_seen:
            print(f"publisher under {args.prefix} terminated", file=sys.stderr)
            return 3
        if time.monotonic() - last_fresh > args.timeout_s:
            print(
                f"no sample on {args.prefix}/{args.topic} for {args.timeout_s} s", file=sys.stderr
            )
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
