"""Which client `Arm` uses by default (`BACKEND`).

"native": the compiled module `dvrk_sidecar._native` (crates/dvrk-py), built by
`pip install ./python` on a machine with Rust; the default whenever it imports.
"pure": iceoryx2's Python binding and ctypes; the fallback when the native module is missing
(`NATIVE_IMPORT_ERROR` says why).

`DVRK_SIDECAR_BACKEND=pure` (or `native`) in the environment chooses one for the whole process;
`Arm(..., backend="pure")` for one Arm. Asking for "native" where it is missing raises
ImportError when the Arm is made, with the reason.
"""

import os

try:
    from . import _native  # noqa: F401

    NATIVE_IMPORT_ERROR = None
except ImportError as e:  # not built (a source checkout on sys.path), or built for another Python
    NATIVE_IMPORT_ERROR = str(e)

CHOICES = ("native", "pure")

_chosen = os.environ.get("DVRK_SIDECAR_BACKEND", "")
CHOICE_ERROR = (
    None
    if _chosen in ("", *CHOICES)
    else f"DVRK_SIDECAR_BACKEND={_chosen!r}: expected 'native' or 'pure' (or unset)"
)
"""Set when the environment names no backend; `Arm()` without `backend=` then raises it."""

BACKEND = _chosen if _chosen in CHOICES else ("native" if NATIVE_IMPORT_ERROR is None else "pure")


def native():
    """The native backend's module (raises ImportError with the reason when it is missing)."""
    if NATIVE_IMPORT_ERROR is not None:
        raise ImportError(f"dvrk_sidecar._native is not available: {NATIVE_IMPORT_ERROR}")
    from . import native as module

    return module
