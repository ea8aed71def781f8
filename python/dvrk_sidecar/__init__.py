"""dvrk_sidecar: a Python client of dvrk-sidecar, the compliance-compensated state of a dVRK PSM
published over iceoryx2 shared memory.

    from dvrk_sidecar import Arm
    arm = Arm("PSM1")                                   # wait="event" | "spin" | "predictive"
    position, velocity, effort = arm.measured_js()      # numpy arrays, 6 joints
    tip = arm.compensated.local.measured_cp()           # 4x4 numpy array, RCM frame

`dvrk_sidecar.BACKEND` says which client `Arm` uses by default: "native" (the compiled module,
built by `pip install ./python` with Rust) or "pure" (iceoryx2's Python binding, the fallback).

`python -m dvrk_sidecar echo PSM1/measured_js --json` prints samples in the same JSON shape as
`dvrk-sidecar echo --json`; `python -m dvrk_sidecar layout` prints the message layouts.
"""

from ._backend import BACKEND, NATIVE_IMPORT_ERROR
from .ipc import WAIT_STRATEGIES, ConfigError, DvrkSidecarError, NoSample, OpenError
from .msg import FLAG_NAMES, JOINT_NAMES, TOPICS


def __getattr__(name):
    # The Arm API needs numpy; the message layouts, `layout` and `echo` do not, so numpy is
    # imported only when the Arm API is first used.
    if name in ("Arm", "Cycle", "Header", "InvalidSample", "pose_matrix"):
        from . import arm

        return getattr(arm, name)
    raise AttributeError(f"module 'dvrk_sidecar' has no attribute {name!r}")

__version__ = "0.1.0"

__all__ = [
    "Arm",
    "BACKEND",
    "Cycle",
    "ConfigError",
    "DvrkSidecarError",
    "FLAG_NAMES",
    "Header",
    "InvalidSample",
    "JOINT_NAMES",
    "NoSample",
    "OpenError",
    "TOPICS",
    "WAIT_STRATEGIES",
    "pose_matrix",
]
