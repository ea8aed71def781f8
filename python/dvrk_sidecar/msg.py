"""The messages dvrk-sidecar publishes, as ctypes structures, and their one JSON shape.

The structures mirror crates/dvrk-ipc/src/msg.rs (and include/dvrk_ipc.h) byte for byte and
declare the same iceoryx2 type names through the `type_name()` classmethod that the iceoryx2
package looks for. iceoryx2 checks only a payload's type name, size and alignment, so a Rust test
(tests/python_client.rs) compares every field offset printed by `python -m dvrk_sidecar layout`
with the Rust types.

Units are SI (m, rad, N m); times are nanoseconds: `sample_t_ns` and `publish_t_ns` on
CLOCK_MONOTONIC (Python's `time.monotonic_ns()`), `sample_realtime_ns` on CLOCK_REALTIME since the
epoch (ROS time, Python's `time.time_ns()`).
"""

import ctypes
import math

from .instruments import INSTRUMENTS

NUM_JOINTS = 6
"""Joints of `measured_js`; the jaw has its own topic (`jaw/measured_js`)."""

JOINT_NAMES = ("yaw", "pitch", "insertion", "roll", "wrist_pitch", "wrist_yaw")
JAW_NAMES = ("jaw",)

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
    "NOT_HOMED",
    "ARM_NOT_ENABLED",
    "CONSOLE_UNKNOWN",
    "NO_INSTRUMENT",
    "INSTRUMENT_UNSUPPORTED",
    "NO_CALIBRATION",
    "BASE_FRAME_STALE",
    "WARMUP",
    "GAP",
    "TRANSIENT",
    "ACCEL_OUT_OF_RANGE",
    "INSERTION_EXTRAPOLATED",
    "INSERTION_OUT_OF_RANGE",
    "STILL_ONLY",
    "REDUCED",
    "POT_MISMATCH",
    "POSITION_OUT_OF_RANGE",
)
"""Names of the bits of `Header.flags` (dvrk_ipc::flags), bit 0 first."""

CONSOLE_STATES = ("UNKNOWN", "DISABLED", "ENABLED", "PAUSED", "FAULT")
"""Codes of the console's operating state in `CompensationStatusV4.source_state` (bits 0-3)."""


def source_state_dict(v: int) -> dict:
    """`CompensationStatusV4.source_state` spelled out (dvrk_ipc msg.rs): the console's state,
    whether it is homed and heard, the parameter set (its index in the file + 1; 0: the only
    one), and the instrument code (0 not known yet, 1 removed, 2 not modelled, 3 + its index in
    the service's instrument catalog)."""
    code = v & 0xF
    return {
        "console_state": CONSOLE_STATES[code] if code < len(CONSOLE_STATES) else "UNKNOWN",
        "homed": bool(v & (1 << 4)),
        "console_heard": bool(v & (1 << 5)),
        "parameter_set": (v >> 8) & 0xFF,
        "instrument": _instrument_name((v >> 16) & 0xFFFF),
    }


def _instrument_name(code: int) -> str:
    if code == 0:
        return "not known"
    if code == 1:
        return "removed"
    if code == 2:
        return "not modelled"
    i = code - 3
    return INSTRUMENTS[i] if i < len(INSTRUMENTS) else f"#{i}"

f64 = ctypes.c_double
u64 = ctypes.c_uint64
u32 = ctypes.c_uint32


class HeaderV2(ctypes.Structure):
    """The header every message starts with, 48 bytes."""

    _fields_ = [
        ("seq", u64),
        ("sample_t_ns", u64),
        ("sample_realtime_ns", u64),
        ("board_timestamp", u64),
        ("publish_t_ns", u64),
        ("valid", u32),
        ("flags", u32),
    ]

    @classmethod
    def type_name(cls) -> str:
        return "dvrk::HeaderV2"


class JointStateV2(ctypes.Structure):
    """`measured_js` and `compensated/measured_js`, 192 bytes (joints in JOINT_NAMES order)."""

    _fields_ = [
        ("header", HeaderV2),
        ("position", f64 * NUM_JOINTS),
        ("velocity", f64 * NUM_JOINTS),
        ("effort", f64 * NUM_JOINTS),
    ]

    @classmethod
    def type_name(cls) -> str:
        return "dvrk::JointStateV2"


class JawStateV1(ctypes.Structure):
    """`jaw/measured_js` and `compensated/jaw/measured_js`, 72 bytes."""

    _fields_ = [
        ("header", HeaderV2),
        ("position", f64),
        ("velocity", f64),
        ("effort", f64),
    ]

    @classmethod
    def type_name(cls) -> str:
        return "dvrk::JawStateV1"


class PoseV2(ctypes.Structure):
    """`local/measured_cp` (RCM frame), `measured_cp` (base frame) and their compensated twins,
    176 bytes; `rotation` is row-major."""

    _fields_ = [
        ("header", HeaderV2),
        ("position_m", f64 * 3),
        ("orientation_xyzw", f64 * 4),
        ("rotation", f64 * 9),
    ]

    @classmethod
    def type_name(cls) -> str:
        return "dvrk::PoseV2"


class CompensationStatusV4(ctypes.Structure):
    """`compensated/status`, 176 bytes."""

    _fields_ = [
        ("header", HeaderV2),
        ("tau_ext_nm", f64 * 2),
        ("delta_rad", f64 * 2),
        ("insertion_m", f64),
        ("cycle_period_ns", u64),
        ("cycle_duration_ns", u64),
        ("cycles_total", u64),
        ("read_failures_total", u64),
        ("overruns_total", u64),
        ("consecutive_read_failures", u32),
        ("source_state", u32),
        ("tau_margin_nm", f64 * 2),
        ("held_sample_age_ns", u64),
        ("publish_late_ns", u64),
        ("implausible_total", u64),
        ("bound_rad", f64 * 2),
        ("tip_bound_m", f64),
        ("weight", f64 * 2),
        ("_reserved", u64),
    ]

    @classmethod
    def type_name(cls) -> str:
        return "dvrk::CompensationStatusV4"


MESSAGE_TYPES = (HeaderV2, JointStateV2, JawStateV1, PoseV2, CompensationStatusV4)

TOPICS = {
    "measured_js": JointStateV2,
    "jaw/measured_js": JawStateV1,
    "local/measured_cp": PoseV2,
    "measured_cp": PoseV2,
    "compensated/measured_js": JointStateV2,
    "compensated/jaw/measured_js": JawStateV1,
    "compensated/local/measured_cp": PoseV2,
    "compensated/measured_cp": PoseV2,
    "compensated/status": CompensationStatusV4,
}
"""The pub-sub topics under an arm's prefix, in the order of the Rust `Topic::ALL` (each cycle
sends the compensated ones first, see `dvrk_ipc::PUBLISH_ORDER`), and their payload types."""

CYCLE_EVENT = "cycle"
"""Event service `<prefix>/cycle`, notified once per cycle after all nine messages."""

CYCLE_FIRST_EVENT = "cycle/first"
"""Event service `<prefix>/cycle/first`, notified once per cycle right after its first message
(`PUBLISH_ORDER[0]`); the native client's subscription of that topic sleeps on it."""

PUBLISH_ORDER = (
    "compensated/local/measured_cp",
    "compensated/measured_cp",
    "compensated/measured_js",
    "compensated/jaw/measured_js",
    "local/measured_cp",
    "measured_cp",
    "measured_js",
    "jaw/measured_js",
    "compensated/status",
)
"""The order in which a cycle's messages are sent (`dvrk_ipc::PUBLISH_ORDER`)."""

_SCALAR_NAMES = {u64: "u64", u32: "u32", f64: "f64"}


def _field_type_name(t) -> str:
    if t in _SCALAR_NAMES:
        return _SCALAR_NAMES[t]
    if issubclass(t, ctypes.Array):
        return f"[{_field_type_name(t._type_)}; {t._length_}]"
    return t.type_name()


def layout(t) -> dict:
    """Size, alignment, type name and every field's offset, size and type of one structure."""
    return {
        "type_name": t.type_name(),
        "size": ctypes.sizeof(t),
        "align": ctypes.alignment(t),
        "fields": [
            {
                "name": name,
                "offset": getattr(t, name).offset,
                "size": getattr(t, name).size,
                "type": _field_type_name(ft),
            }
            for name, ft in t._fields_
        ],
    }


def layouts() -> list:
    """The layouts of every message type (what `python -m dvrk_sidecar layout` prints)."""
    return [layout(t) for t in MESSAGE_TYPES]


def split_service(service: str, default_prefix: str = "PSM1"):
    """`"PSM1/compensated/measured_cp"` -> `("PSM1", "compensated/measured_cp")`, as
    `dvrk-sidecar echo` reads it: a leading '/' (ROS style) is dropped, a bare topic
    (`local/measured_cp`) is under `default_prefix`.

    The topic is the longest known suffix, so prefixes with slashes work. Raises ValueError
    naming the service and the known topics otherwise."""
    service = service.lstrip("/")
    if service in TOPICS:
        return default_prefix, service
    for topic in sorted(TOPICS, key=len, reverse=True):
        if service.endswith("/" + topic) and len(service) > len(topic) + 1:
            return service[: -len(topic) - 1], topic
    raise ValueError(
        f'"{service}" is not a dvrk-sidecar service; expected <prefix>/<topic> (e.g. '
        f"PSM1/measured_js) with topic one of: {', '.join(TOPICS)}"
    )


def flag_names(flags: int) -> list:
    """The names of the defined bits set in `flags`, bit 0 first; reserved bits are skipped, as
    dvrk_ipc::flags::names does."""
    return [name for bit, name in enumerate(FLAG_NAMES) if flags & (1 << bit)]


def _num(x):
    """A float as JSON has it: a non-finite one is null, as serde_json writes it."""
    return x if math.isfinite(x) else None


def _nums(xs) -> list:
    return [_num(x) for x in xs]


def header_json(h: HeaderV2) -> dict:
    """The header as the one JSON shape has it (valid a boolean, flags as names)."""
    return {
        "seq": h.seq,
        "sample_t_ns": h.sample_t_ns,
        "sample_realtime_ns": h.sample_realtime_ns,
        "publish_t_ns": h.publish_t_ns,
        "board_timestamp": h.board_timestamp,
        "valid": h.valid != 0,
        "flags": flag_names(h.flags),
    }


def body_json(msg) -> dict:
    """The body of a message in the one JSON shape (without topic and header)."""
    if isinstance(msg, JointStateV2):
        return {
            "name": list(JOINT_NAMES),
            "position": _nums(msg.position),
            "velocity": _nums(msg.velocity),
            "effort": _nums(msg.effort),
        }
    if isinstance(msg, JawStateV1):
        return {
            "name": list(JAW_NAMES),
            "position": [_num(msg.position)],
            "velocity": [_num(msg.velocity)],
            "effort": [_num(msg.effort)],
        }
    if isinstance(msg, PoseV2):
        r = _nums(msg.rotation)
        return {
            "position_m": _nums(msg.position_m),
            "orientation_xyzw": _nums(msg.orientation_xyzw),
            "rotation": [r[0:3], r[3:6], r[6:9]],
        }
    if isinstance(msg, CompensationStatusV4):
        out = {}
        for name, _ in CompensationStatusV4._fields_:
            if name in ("header", "_reserved"):
                continue
            v = getattr(msg, name)
            if isinstance(v, ctypes.Array):
                out[name] = _nums(v)
            else:
                out[name] = _num(v) if isinstance(v, float) else v
        out["source"] = source_state_dict(msg.source_state)
        return out
    raise TypeError(f"not a dvrk-sidecar message: {type(msg).__name__}")


def to_json(service: str, msg) -> dict:
    """`{"topic": service, "header": {...}, ...body}`: the shape `dvrk-sidecar echo --json`
    prints for the same message."""
    out = {"topic": service, "header": header_json(msg.header)}
    out.update(body_json(msg))
    return out


def _check_layouts() -> None:
    """The sizes the Rust const assertions fix; a mismatch is a bug in this file."""
    for t, size in (
        (HeaderV2, 48),
        (JointStateV2, 192),
        (JawStateV1, 72),
        (PoseV2, 176),
        (CompensationStatusV4, 224),
    ):
        if ctypes.sizeof(t) != size or ctypes.alignment(t) != 8:
            raise ImportError(
                f"dvrk_sidecar.msg.{t.__name__} is {ctypes.sizeof(t)} bytes aligned to "
                f"{ctypes.alignment(t)}, expected {size} aligned to 8"
            )


_check_layouts()
