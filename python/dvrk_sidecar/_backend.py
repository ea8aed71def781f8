"""Which client `Arm` uses by default. The compiled module `dvrk_sidecar._native` (built by
`pip install ./python` on a machine with Rust) is opt-in for now: `Arm(..., backend="native")`,
or `DVRK_SIDECAR_BACKEND=native` in the environment. Two of the package's own IPC tests (a
publisher written in Python, and the refusal of a service of another type) do not pass on it
yet, so the default stays the pure-Python client, which passes them all."""

import os

try:
    from . import _native  # noqa: F401

    NATIVE_IMPORT_ERROR = None
except ImportError as e:  # not built (a source checkout on sys.path), or built for another Python
    NATIVE_IMPORT_ERROR = str(e)

BACKEND = (
    "native"
    if os.environ.get("DVRK_SIDECAR_BACKEND") == "native" and NATIVE_IMPORT_ERROR is None
    else "pure"
)


def native():
    """The native backend's module (raises ImportError with the reason when it is missing)."""
    if NATIVE_IMPORT_ERROR is not None:
        raise ImportError(f"dvrk_sidecar._native is not available: {NATIVE_IMPORT_ERROR}")
    from . import native as module

    return module
