"""`Arm`: a crtk-like client of one arm published by dvrk-sidecar.

    arm = Arm("PSM1")
    position, velocity, effort = arm.measured_js()
    tip = arm.compensated.local.measured_cp()          # 4x4 numpy array, RCM frame
    jaw, _, _ = arm.jaw.measured_js()
    p, v, e, header = arm.measured_js(extra=True)      # header.seq, header.stamp, header.flags
    cycle = arm.read_cycle()                           # the nine messages of one cycle

Getters follow the crtk Python client: `age` is the oldest cached sample (seconds since it was
sampled) a call accepts without waiting, `wait` is how long it then waits for a new one; both
default to the Arm's. With `extra=True` a getter also returns the message's `Header`.

An invalid sample (header `valid` false: a failed board read, an implausible or held sample, no
source) is never returned as if it were valid: the getter raises `InvalidSample`, which carries
the header (with the flags naming why) and the value, for a caller that wants it anyway.
No sample in time raises `NoSample` (a `TimeoutError`), saying whether a publisher is connected.
"""

import ctypes
import dataclasses
import math
import time

import numpy

from . import ipc, msg


@dataclasses.dataclass(frozen=True)
class Header:
    """A message's header. Times in ns: `sample_t_ns`, `publish_t_ns` on CLOCK_MONOTONIC
    (`time.monotonic_ns()`), `sample_realtime_ns` on CLOCK_REALTIME (ROS time)."""

    seq: int
    sample_t_ns: int
    sample_realtime_ns: int
    board_timestamp: int
    publish_t_ns: int
    valid: bool
    flags: tuple

    @property
    def stamp(self) -> float:
        """The sampling instant in ROS time, seconds since the epoch (crtk's `header.stamp`)."""
        return self.sample_realtime_ns * 1e-9

    @classmethod
    def from_msg(cls, h: msg.HeaderV2) -> "Header":
        return cls(
            seq=h.seq,
            sample_t_ns=h.sample_t_ns,
            sample_realtime_ns=h.sample_realtime_ns,
            board_timestamp=h.board_timestamp,
            publish_t_ns=h.publish_t_ns,
            valid=h.valid != 0,
            flags=tuple(msg.flag_names(h.flags)),
        )


class InvalidSample(ipc.DvrkSidecarError):
    """The newest sample of a topic is marked invalid. `header` says why (its flags), `value`
    is what the getter would have returned."""

    def __init__(self, service: str, header: Header, value):
        flags = ", ".join(header.flags) or "no flags"
        super().__init__(f"{service} seq {header.seq} is invalid ({flags})")
        self.service = service
        self.header = header
        self.value = value


def pose_matrix(p: msg.PoseV2) -> numpy.ndarray:
    """A PoseV2 as a 4x4 homogeneous transform (metres)."""
    m = numpy.eye(4)
    m[:3, :3] = numpy.array(p.rotation).reshape(3, 3)
    m[:3, 3] = p.position_m
    return m


def _status_dict(s: msg.CompensationStatusV4) -> dict:
    """The status as a dict with the message's field names; pairs as numpy arrays."""
    out = {}
    for name, _ in msg.CompensationStatusV4._fields_:
        if name not in ("header", "_reserved"):
            v = getattr(s, name)
            out[name] = numpy.array(v) if isinstance(v, ctypes.Array) else v
    out["source"] = msg.source_state_dict(s.source_state)
    return out


class _Source:
    """Where a view reads: the arm plus a topic prefix ("" or "compensated/")."""

    def __init__(self, arm: "Arm", base: str):
        self._arm = arm
        self._base = base

    def _read(self, topic, age, wait, convert, extra):
        return self._arm._read(self._base + topic, age, wait, convert, extra)


class _JawView(_Source):
    """`<prefix>/[compensated/]jaw/measured_js`."""

    def measured_js(self, age=None, wait=None, extra=False):
        """Jaw position (rad), velocity (rad/s), effort (N m) as 1-element numpy arrays."""
        return self._read(
            "jaw/measured_js",
            age,
            wait,
            lambda m: (numpy.array([m.position]), numpy.array([m.velocity]), numpy.array([m.effort])),
            extra,
        )

    def measured_jp(self, age=None, wait=None, extra=False):
        return self._read("jaw/measured_js", age, wait, lambda m: numpy.array([m.position]), extra)

    def measured_jv(self, age=None, wait=None, extra=False):
        return self._read("jaw/measured_js", age, wait, lambda m: numpy.array([m.velocity]), extra)

    def measured_jf(self, age=None, wait=None, extra=False):
        return self._read("jaw/measured_js", age, wait, lambda m: numpy.array([m.effort]), extra)


class _LocalView(_Source):
    """`<prefix>/[compensated/]local/measured_cp`: the tip in the RCM frame."""

    def measured_cp(self, age=None, wait=None, extra=False):
        """The tip pose in the RCM frame, a 4x4 numpy array (metres)."""
        return self._read("local/measured_cp", age, wait, pose_matrix, extra)


class _ArmView(_Source):
    """The measured (or compensated) state of the arm."""

    def __init__(self, arm, base):
        super().__init__(arm, base)
        self.jaw = _JawView(arm, base)
        self.local = _LocalView(arm, base)

    def measured_js(self, age=None, wait=None, extra=False):
        """Position (rad, insertion m), velocity, effort (N m, insertion N) of the 6 joints
        (`msg.JOINT_NAMES`) as numpy arrays; with extra=True the Header follows."""
        return self._read(
            "measured_js",
            age,
            wait,
            lambda m: (numpy.array(m.position), numpy.array(m.velocity), numpy.array(m.effort)),
            extra,
        )

    def measured_jp(self, age=None, wait=None, extra=False):
        return self._read("measured_js", age, wait, lambda m: numpy.array(m.position), extra)

    def measured_jv(self, age=None, wait=None, extra=False):
        return self._read("measured_js", age, wait, lambda m: numpy.array(m.velocity), extra)

    def measured_jf(self, age=None, wait=None, extra=False):
        return self._read("measured_js", age, wait, lambda m: numpy.array(m.effort), extra)

    def measured_cp(self, age=None, wait=None, extra=False):
        """The tip pose in the base frame (base_frame x local), a 4x4 numpy array (metres)."""
        return self._read("measured_cp", age, wait, pose_matrix, extra)


class _CompensatedView(_ArmView):
    def status(self, age=None, wait=None, extra=False):
        """`compensated/status` as a dict with the message's field names (the JSON body)."""
        return self._read("status", age, wait, _status_dict, extra)


class Arm(_ArmView):
    """A client of the arm `name` (the service prefix, default `PSM1`).

    wait: how to wait for samples, "event" (sleep until the sidecar notifies a cycle),
        "spin" (poll, one whole core) or "predictive" (sleep until just before the next sample
        is due, then poll).
    domain, root: the iceoryx2 domain (file-name prefix, e.g. "t123_") and its root path (e.g.
        "/tmp/iox2t/"); None for iceoryx2's defaults, where `dvrk-sidecar serve` publishes.
    age, timeout: the getters' default `age` and `wait`, seconds.

    One Arm is used from one thread at a time. `close()` (or a `with` block) releases its ports.
    """

    def __init__(
        self,
        name: str = "PSM1",
        wait: str = "event",
        domain=None,
        root=None,
        age: float = 0.01,
        timeout: float = 0.5,
        period_s: float = ipc.NOMINAL_PERIOD_NS * 1e-9,
    ):
        super().__init__(self, "")
        self.name = ipc.check_prefix(name)
        for what, v in (("age", age), ("timeout", timeout), ("period_s", period_s)):
            number = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            if not number or v < 0 or (what == "period_s" and v == 0):
                raise ipc.ConfigError(f"{what} {v!r}: must be a finite number of seconds >= 0")
        self.age = float(age)
        self.timeout = float(timeout)
        self.compensated = _CompensatedView(self, "compensated/")
        self._node = ipc.create_node("dvrk-sidecar-python", domain, root)
        self._readers = {t: ipc.Reader(self._node, self.name, t) for t in msg.TOPICS}
        self._waiter = ipc.Waiter(self._node, self.name, wait, int(period_s * 1e9))

    @property
    def wait_strategy(self) -> str:
        return self._waiter.strategy

    def _reader(self, topic):
        try:
            return self._readers[topic]
        except KeyError:
            raise ipc.DvrkSidecarError(f"{self!r} is closed") from None

    def _read(self, topic, age, wait, convert, extra):
        reader = self._reader(topic)
        age = self.age if age is None else age
        wait = self.timeout if wait is None else wait
        value = reader.take_newest()
        if value is None:
            value = reader.last
        now = time.monotonic_ns()
        if value is None or now - value.header.sample_t_ns > age * 1e9:
            value = self._waiter.wait_for(reader.take_newest, now + int(wait * 1e9))
            if value is None:
                raise reader.no_sample(wait)
        else:
            self._waiter.observe(value.header)
        header = Header.from_msg(value.header)
        result = convert(value)
        if not header.valid:
            raise InvalidSample(reader.service_name, header, result)
        if extra:
            return (*result, header) if isinstance(result, tuple) else (result, header)
        return result

    def wait_for_cycle(self, timeout=None):
        """Waits for the next cycle the sidecar publishes (its last message, the status, has
        arrived) and returns that cycle's Header (valid or not); None after `timeout` seconds
        (default: the Arm's)."""
        reader = self._reader("compensated/status")
        reader.take_newest()  # what has already arrived is not the next cycle
        timeout = self.timeout if timeout is None else timeout
        value = self._waiter.wait_for(reader.take_newest, time.monotonic_ns() + int(timeout * 1e9))
        return None if value is None else Header.from_msg(value.header)

    def read_cycle(self, timeout=None):
        """Waits for the next cycle and returns all nine of its messages as a `Cycle` (the same
        getters as the Arm, every one of the same seq); None after `timeout` seconds. A cycle of
        which a message was overwritten before it was read (the caller was descheduled for
        several cycles) is skipped for the next one."""
        timeout = self.timeout if timeout is None else timeout
        deadline = time.monotonic() + timeout
        while True:
            header = self.wait_for_cycle(max(0.0, deadline - time.monotonic()))
            if header is None:
                return None
            messages = {}
            for topic, reader in self._readers.items():
                reader.take_newest()
                messages[topic] = reader.find(header.seq)
            if all(m is not None for m in messages.values()):
                return Cycle(self.name, messages)

    def close(self) -> None:
        """Releases the subscribers and the listener (the node goes with the Arm)."""
        for r in self._readers.values():
            r.close()
        self._readers = {}
        self._waiter.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __repr__(self) -> str:
        return f"Arm({self.name!r}, wait={self.wait_strategy!r})"


class Cycle(_ArmView):
    """The nine messages of one cycle, read by `Arm.read_cycle()`: the Arm's getters
    (`measured_js()`, `jaw.measured_js()`, `local.measured_cp()`, `compensated...`,
    `compensated.status()`; their `age` and `wait` are ignored), all of cycle `seq`. A getter of
    an invalid message raises InvalidSample as the Arm's do."""

    def __init__(self, name: str, messages: dict):
        super().__init__(self, "")
        self.compensated = _CompensatedView(self, "compensated/")
        self.name = name
        self._messages = messages
        self.header = Header.from_msg(messages["compensated/status"].header)
        self.seq = self.header.seq

    def _read(self, topic, age, wait, convert, extra):
        value = self._messages[topic]
        header = Header.from_msg(value.header)
        result = convert(value)
        if not header.valid:
            raise InvalidSample(f"{self.name}/{topic}", header, result)
        if extra:
            return (*result, header) if isinstance(result, tuple) else (result, header)
        return result

    def __repr__(self) -> str:
        return f"Cycle({self.name!r}, seq={self.seq})"
