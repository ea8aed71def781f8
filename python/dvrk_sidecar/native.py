"""The native backend of `Arm`: `dvrk_sidecar._native` (Rust, dvrk-ipc) waits in compiled code
with the GIL released and returns each sample as one numpy array of shape (1,) whose structured
dtype is the message's ctypes layout (`msg`); a getter's arrays are views of it, not copies
(`measured_cp()` builds its 4x4 matrix, which the message does not hold).

Per topic an Arm opens one subscription, when a getter first reads it, with the Arm's wait
strategy (event and predictive: one listener of the cycle event each); `read_cycle()` adds
listener-free subscriptions of the other topics. `_native.Subscription` is also usable on its own:

    from dvrk_sidecar import _native, native
    node = _native.Node()
    sub = _native.Subscription(node, "PSM1", "compensated/local/measured_cp",
                               native.DTYPES["compensated/local/measured_cp"], wait="predictive")
    a = sub.wait(timeout=0.5)          # numpy array (1,) of the PoseV2 dtype, or None
    a["position_m"][0], a["header"]["seq"][0]
"""

import numpy

from . import _native, ipc, msg
from .arm import Header, _status_fields

DTYPES = {topic: numpy.dtype(t) for topic, t in msg.TOPICS.items()}
"""The numpy structured dtype of each topic's message (from its ctypes layout)."""


def header(a) -> Header:
    """The Header of a message array."""
    seq, t, rt, board, pub, valid, flags = a["header"][0].item()
    return Header(
        seq=seq,
        sample_t_ns=t,
        sample_realtime_ns=rt,
        board_timestamp=board,
        publish_t_ns=pub,
        valid=valid != 0,
        flags=tuple(msg.flag_names(flags)),
    )


def pose_matrix(a) -> numpy.ndarray:
    """A PoseV2 array as a 4x4 homogeneous transform (metres)."""
    m = numpy.eye(4)
    m[:3, :3] = a["rotation"].reshape(3, 3)
    m[:3, 3] = a["position_m"].reshape(3)
    return m


def _status_dict(a) -> dict:
    out = {}
    for name in _status_fields():
        v = a[name][0]
        out[name] = v if v.ndim else v.item()
    return out


NATIVE_CONVERT = {
    # reshape(-1) is a view: (1, 6) -> (6,) for the joints, (1,) stays (1,) for the jaw.
    "js": lambda a: (a["position"].reshape(-1), a["velocity"].reshape(-1), a["effort"].reshape(-1)),
    "jp": lambda a: a["position"].reshape(-1),
    "jv": lambda a: a["velocity"].reshape(-1),
    "jf": lambda a: a["effort"].reshape(-1),
    "pose": pose_matrix,
    "status": _status_dict,
}


def _open_error(e, what=None):
    reason = str(e)
    return ipc.OpenError(f"{what + ': ' if what else ''}{reason}{ipc._hint(reason)}")


class NativeBackend:
    name = "native"
    convert = NATIVE_CONVERT
    header = staticmethod(header)

    def __init__(self, arm_name, wait, domain, root, period_ns):
        try:
            self._node = _native.Node("dvrk-sidecar-python", domain, root)
        except ValueError as e:
            raise ipc.ConfigError(str(e)) from None
        except _native.NativeError as e:
            where = f"domain {domain!r}" if domain else "the default domain"
            raise _open_error(e, f"creating an iceoryx2 node in {where}") from e
        try:
            # All of the arm's services now, as the pure client does: one of another type or
            # QoS is refused here, by name ("opening PSM1/measured_js as dvrk::JointStateV2:
            # ...IncompatibleTypes"), not when a getter first reads it.
            self._services = _native.ArmServices(self._node, arm_name)
        except ValueError as e:
            raise ipc.ConfigError(str(e)) from None
        except _native.NativeError as e:
            raise _open_error(e) from e
        self._arm = arm_name
        self._prefix = domain or ipc.default_domain_prefix()
        self._root = root or ipc.default_root()
        self.strategy = wait
        self._period_ns = period_ns
        self._subs = {}
        self._quiet = {}
        self._last = {}
        self._closed = False

    def _open(self, topic, wait):
        if self._closed:
            raise ipc.DvrkSidecarError("the Arm is closed")
        try:
            return _native.Subscription(
                self._node, self._arm, topic, DTYPES[topic], wait=wait, period_ns=self._period_ns
            )
        except _native.NativeError as e:
            raise _open_error(e, f"opening {self._arm}/{topic}") from e

    def _sub(self, topic):
        s = self._subs.get(topic)
        if s is None:
            s = self._subs[topic] = self._open(topic, self.strategy)
        return s

    def newest(self, topic):
        a = self._sub(topic).take()
        if a is not None:
            self._last[topic] = a
        return a

    def last(self, topic):
        return self._last.get(topic)

    def wait(self, topic, until_ns):
        import time

        a = self._sub(topic).wait(max(0, until_ns - time.monotonic_ns()) * 1e-9)
        if a is not None:
            self._last[topic] = a
        return a

    def observe(self, topic, value):
        pass  # the native subscription learns from every sample it drains

    def zero(self, topic):
        return numpy.zeros(1, DTYPES[topic])

    def service_name(self, topic):
        return f"{self._arm}/{topic}"

    def no_sample(self, topic, waited_s):
        if self._sub(topic).publishers() == 0:
            why = "no publisher is connected (is `dvrk-sidecar serve` running with this prefix and domain?)"
            why += ipc.no_publisher_hint(self._root, self._prefix)
        else:
            why = "a publisher is connected but sent nothing"
        return ipc.NoSample(f"no sample on {self._arm}/{topic} within {waited_s:g} s: {why}")

    def cycle(self, until_ns, all_topics=False):
        import time

        if all_topics:
            for topic in msg.TOPICS:  # before the wait: a new subscriber gets the next cycle
                if topic != "compensated/status":
                    self._quiet_sub(topic)
        s = self._sub("compensated/status")
        s.take()  # what has already arrived is not the next cycle
        a = s.wait(max(0, until_ns - time.monotonic_ns()) * 1e-9)
        if a is not None:
            self._last["compensated/status"] = a
        return a

    def _quiet_sub(self, topic):
        s = self._quiet.get(topic)
        if s is None:
            s = self._quiet[topic] = self._open(topic, "spin")  # no listener
        return s

    def cycle_messages(self, seq):
        messages = {"compensated/status": self._last["compensated/status"]}
        for topic in msg.TOPICS:
            if topic == "compensated/status":
                continue
            s = self._quiet_sub(topic)
            a = s.take()
            if a is None:
                a = s.latest()
            if a is None or int(a["header"]["seq"][0]) != seq:
                return None
            messages[topic] = a
        return messages

    def close(self):
        for s in (*self._subs.values(), *self._quiet.values()):
            s.close()
        self._subs = {}
        self._quiet = {}
        self._services = None
        self._closed = True
