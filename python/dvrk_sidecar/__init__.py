"""dvrk_sidecar: a Python client of dvrk-sidecar, the compliance-compensated state of a dVRK PSM
published over iceoryx2 shared memory.

    from dvrk_sidecar import Arm
    arm = Arm("PSM1")                                   # wait="event" | "spin" | "predictive"
    position, velocity, effort = arm.measured_js()      # numpy arrays, 6 joints
    tip = arm.compensated.local.measured_cp()           # 4x4 numpy array, RCM frame

`python -m dvrk_sidecar echo PSM1/measured_js --json` prints samples in the same JSON shape as
`dvrk-sidecar echo --json`; `python -m dvrk_sidecar layout` prints the message layouts.
"""

from .arm import Arm, Header, InvalidSample, pose_matrix
from .ipc import WAIT_STRATEGIES, ConfigError, DvrkSidecarError, NoSample
from .msg import FLAG_NAMES, JOINT_NAMES, TOPICS

__version__ = "0.1.0"

__all__ = [
    "Arm",
    "ConfigError",
    "DvrkSidecarError",
    "FLAG_NAMES",
    "Header",
    "InvalidSample",
    "JOINT_NAMES",
    "NoSample",
    "TOPICS",
    "WAIT_STRATEGIES",
    "pose_matrix",
]
