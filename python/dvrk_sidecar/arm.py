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


def _status_fields():
    return [n for n, _ in msg.CompensationStatusV4._fields_ if n not in ("header", "_reserved")]


def _status_dict(s: msg.CompensationStatusV4) -> dict:
    """The status as a dict with the message's field names; pairs as numpy arrays."""
    out = {}
    for name in _status_fields():
        v = getattr(s, name)
        out[name] = numpy.array(v) if isinstance(v, ctypes.Array) else v
    out["source"] = msg.source_state_dict(s.source_state)
    return out


class _Source:
    """Where a view reads: the arm plus a topic prefix ("" or "compensated/")."""

    def __init__(self, arm: "Arm", base: str):
        self._arm = arm
        self._base = base

    def _read(self, topic, kind, age, wait, extra, stamped):
        return self._arm._read(self._base + topic, kind, age, wait, extra, stamped)


class _JawView(_Source):
    """`<prefix>/[compensated/]jaw/measured_js`."""

    def measured_js(self, age=None, wait=None, extra=False, stamped=False):
        """Jaw position (rad), velocity (rad/s), effort (N m) as 1-element numpy arrays."""
        return self._read("jaw/measured_js", "js", age, wait, extra, stamped)

    def measured_jp(self, age=None, wait=None, extra=False, stamped=False):
        return self._read("jaw/measured_js", "jp", age, wait, extra, stamped)

    def measured_jv(self, age=None, wait=None, extra=False, stamped=False):
        return self._read("jaw/measured_js", "jv", age, wait, extra, stamped)

    def measured_jf(self, age=None, wait=None, extra=False, stamped=False):
        return self._read("jaw/measured_js", "jf", age, wait, extra, stamped)


class _LocalView(_Source):
    """`<prefix>/[compensated/]local/measured_cp`: the tip in the RCM frame."""

    def measured_cp(self, age=None, wait=None, extra=False, stamped=False):
        """The tip pose in the RCM frame, a 4x4 numpy array (metres)."""
        return self._read("local/measured_cp", "pose", age, wait, extra, stamped)


class _ArmView(_Source):
    """The measured (or compensated) state of the arm."""

    def __init__(self, arm, base):
        super().__init__(arm, base)
        self.jaw = _JawView(arm, base)
        self.local = _LocalView(arm, base)

    def measured_js(self, age=None, wait=None, extra=False, stamped=False):
        """Position (rad, insertion m), velocity, effort (N m, insertion N) of the 6 joints
        (`msg.JOINT_NAMES`) as numpy arrays; with extra=True the Header follows, with
        stamped=True the timestamp (0.0: invalid)."""
        return self._read("measured_js", "js", age, wait, extra, stamped)

    def measured_jp(self, age=None, wait=None, extra=False, stamped=False):
        return self._read("measured_js", "jp", age, wait, extra, stamped)

    def measured_jv(self, age=None, wait=None, extra=False, stamped=False):
        return self._read("measured_js", "jv", age, wait, extra, stamped)

    def measured_jf(self, age=None, wait=None, extra=False, stamped=False):
        return self._read("measured_js", "jf", age, wait, extra, stamped)

    def measured_cp(self, age=None, wait=None, extra=False, stamped=False):
        """The tip pose in the base frame (base_frame x local), a 4x4 numpy array (metres)."""
        return self._read("measured_cp", "pose", age, wait, extra, stamped)


class _CompensatedView(_ArmView):
    def status(self, age=None, wait=None, extra=False, stamped=False):
        """`compensated/status` as a dict with the message's field names (the JSON body)."""
        return self._read("status", "status", age, wait, extra, stamped)


def _as_array(x):
    """A ctypes array or scalar field as a new numpy array (1 element for a scalar)."""
    return numpy.array(x) if isinstance(x, ctypes.Array) else numpy.array([x])


PURE_CONVERT = {
    "js": lambda m: (_as_array(m.position), _as_array(m.velocity), _as_array(m.effort)),
    "jp": lambda m: _as_array(m.position),
    "jv": lambda m: _as_array(m.velocity),
    "jf": lambda m: _as_array(m.effort),
    "pose": pose_matrix,
    "status": _status_dict,
}
"""What a getter returns, from a ctypes message (the pure backend)."""


def _shape(result, header, extra, stamped):
    """A getter's return value: the data, then the Header (extra) and/or the stamp (stamped)."""
    tail = ()
    if extra:
        tail += (header,)
    if stamped:
        tail += (header.stamp if header.valid else 0.0,)
    if not tail:
        return result
    return (*result, *tail) if isinstance(result, tuple) else (result, *tail)


class _PureBackend:
    """The pure-Python client: iceoryx2's Python binding, one listener per Arm."""

    name = "pure"
    convert = PURE_CONVERT

    def __init__(self, arm_name, wait, domain, root, period_ns):
        self._node = ipc.create_node("dvrk-sidecar-python", domain, root)
        self._readers = {t: ipc.Reader(self._node, arm_name, t) for t in msg.TOPICS}
        self._waiter = ipc.Waiter(self._node, arm_name, wait, period_ns)
        self.strategy = self._waiter.strategy

    def _reader(self, topic):
        try:
            return self._readers[topic]
        except KeyError:
            raise ipc.DvrkSidecarError("the Arm is closed") from None

    def newest(self, topic):
        return self._reader(topic).take_newest()

    def last(self, topic):
        return self._reader(topic).last

    def wait(self, topic, until_ns):
        return self._waiter.wait_for(self._reader(topic).take_newest, until_ns)

    def observe(self, topic, value):
        self._waiter.observe(value.header)

    @staticmethod
    def header(value):
        return Header.from_msg(value.header)

    def zero(self, topic):
        return msg.TOPICS[topic]()

    def no_sample(self, topic, waited_s):
        return self._reader(topic).no_sample(waited_s)

    def service_name(self, topic):
        return self._reader(topic).service_name

    def cycle(self, until_ns, all_topics=False):
        """Waits for the next cycle; returns its status message, None on timeout."""
        reader = self._reader("compensated/status")
        reader.take_newest()  # what has already arrived is not the next cycle
        value = self._waiter.wait_for(reader.take_newest, until_ns)
        return value

    def cycle_messages(self, seq):
        """The nine messages of cycle `seq`, None when one was already overwritten."""
        messages = {}
        for topic, reader in self._readers.items():
            reader.take_newest()
            messages[topic] = reader.find(seq)
        return messages if all(m is not None for m in messages.values()) else None

    def close(self):
        for r in self._readers.values():
            r.close()
        self._readers = {}
        self._waiter.close()


class Arm(_ArmView):
    """A client of the arm `name` (the service prefix, default `PSM1`).

    wait: how to wait for samples, "event" (sleep until the sidecar notifies a cycle),
        "spin" (poll, one whole core) or "predictive" (sleep until just before the next sample
        is due, then poll).
    domain, root: the iceoryx2 domain (file-name prefix, e.g. "t123_") and its root path (e.g.
        "/tmp/iox2t/"); None for the project's defaults (dvrk_<uid>_ under /tmp/dvrk-sidecar-<uid>/
        or $DVRK_SIDECAR_IPC_ROOT), where `dvrk-sidecar serve` publishes.
    age, timeout: the getters' default `age` and `wait`, seconds.
    backend: "native" (the compiled module: waits with the GIL released, numpy views of one
        array per message), "pure" (iceoryx2's Python binding), or None: native when it
        imports (`dvrk_sidecar.BACKEND`), else pure.

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
        backend=None,
    ):
        super().__init__(self, "")
        self.name = ipc.check_prefix(name)
        for what, v in (("age", age), ("timeout", timeout), ("period_s", period_s)):
            number = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            if not number or v < 0 or (what == "period_s" and v == 0):
                raise ipc.ConfigError(f"{what} {v!r}: must be a finite number of seconds >= 0")
        if wait not in ipc.WAIT_STRATEGIES:
            raise ipc.ConfigError(f"wait {wait!r}: expected one of {', '.join(ipc.WAIT_STRATEGIES)}")
        self.age = float(age)
        self.timeout = float(timeout)
        self.compensated = _CompensatedView(self, "compensated/")
        from . import _backend

        if backend is None:
            if _backend.CHOICE_ERROR:
                raise ipc.ConfigError(_backend.CHOICE_ERROR)
            backend = _backend.BACKEND
        if backend == "native":
            self._backend = _backend.native().NativeBackend(self.name, wait, domain, root, int(period_s * 1e9))
        elif backend == "pure":
            self._backend = _PureBackend(self.name, wait, domain, root, int(period_s * 1e9))
        else:
            raise ipc.ConfigError(f"backend {backend!r}: expected 'native', 'pure' or None")

    @property
    def wait_strategy(self) -> str:
        return self._backend.strategy

    @property
    def backend(self) -> str:
        """"native" or "pure": which client this Arm uses."""
        return self._backend.name

    def _read(self, topic, kind, age, wait, extra, stamped):
        b = self._backend
        age = self.age if age is None else age
        wait = self.timeout if wait is None else wait
        value = b.newest(topic)
        if value is None:
            value = b.last(topic)
        now = time.monotonic_ns()
        header = None if value is None else b.header(value)
        if header is None or now - header.sample_t_ns > age * 1e9:
            value = b.wait(topic, now + int(wait * 1e9))
            if value is None:
                if stamped:
                    # dVRK 2.4 convention: no exception, a zero timestamp says "no valid data".
                    zero = b.header(b.zero(topic))
                    return _shape(b.convert[kind](b.zero(topic)), zero, extra, stamped)
                raise b.no_sample(topic, wait)
            header = b.header(value)
        else:
            b.observe(topic, value)
        result = b.convert[kind](value)
        if not header.valid and not stamped:
            raise InvalidSample(b.service_name(topic), header, result)
        return _shape(result, header, extra, stamped)

    def wait_for_cycle(self, timeout=None):
        """Waits for the next cycle the sidecar publishes (its last message, the status, has
        arrived) and returns that cycle's Header (valid or not); None after `timeout` seconds
        (default: the Arm's)."""
        return self._wait_for_cycle(timeout, False)

    def _wait_for_cycle(self, timeout, all_topics):
        timeout = self.timeout if timeout is None else timeout
        value = self._backend.cycle(time.monotonic_ns() + int(timeout * 1e9), all_topics)
        return None if value is None else self._backend.header(value)

    def read_cycle(self, timeout=None):
        """Waits for the next cycle and returns all nine of its messages as a `Cycle` (the same
        getters as the Arm, every one of the same seq); None after `timeout` seconds. A cycle of
        which a message was overwritten before it was read (the caller was descheduled for
        several cycles) is skipped for the next one."""
        timeout = self.timeout if timeout is None else timeout
        deadline = time.monotonic() + timeout
        while True:
            header = self._wait_for_cycle(max(0.0, deadline - time.monotonic()), True)
            if header is None:
                return None
            messages = self._backend.cycle_messages(header.seq)
            if messages is not None:
                return Cycle(self.name, messages, self._backend)

    def close(self) -> None:
        """Releases the subscribers and the listener (the node goes with the Arm)."""
        self._backend.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __repr__(self) -> str:
        return f"Arm({self.name!r}, wait={self.wait_strategy!r}, backend={self.backend!r})"


class Cycle(_ArmView):
    """The nine messages of one cycle, read by `Arm.read_cycle()`: the Arm's getters
    (`measured_js()`, `jaw.measured_js()`, `local.measured_cp()`, `compensated...`,
    `compensated.status()`; their `age` and `wait` are ignored), all of cycle `seq`. A getter of
    an invalid message raises InvalidSample as the Arm's do."""

    def __init__(self, name: str, messages: dict, backend=None):
        super().__init__(self, "")
        self.compensated = _CompensatedView(self, "compensated/")
        self.name = name
        self._messages = messages
        self._backend = backend or _PureBackend
        self.header = self._backend.header(messages["compensated/status"])
        self.seq = self.header.seq

    def _read(self, topic, kind, age, wait, extra, stamped):
        value = self._messages[topic]
        header = self._backend.header(value)
        result = self._backend.convert[kind](value)
        if not header.valid and not stamped:
            raise InvalidSample(f"{self.name}/{topic}", header, result)
        return _shape(result, header, extra, stamped)

    def __repr__(self) -> str:
        return f"Cycle({self.name!r}, seq={self.seq})"
