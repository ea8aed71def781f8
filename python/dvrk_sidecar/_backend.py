"""Which client `Arm` uses by default: the compiled module `dvrk_sidecar._native` (built by
`pip install ./python` on a machine with Rust) when it imports, else the pure-Python one."""

try:
    from . import _native  # noqa: F401

    BACKEND = "native"
    NATIVE_IMPORT_ERROR = None
except ImportError as e:  # not built (a source checkout on sys.path), or built for another Python
    BACKEND = "pure"
    NATIVE_IMPORT_ERROR = str(e)


def native():
    """The native backend's module (raises ImportError with the reason when it is missing)."""
    if NATIVE_IMPORT_ERROR is not None:
        raise ImportError(f"dvrk_sidecar._native is not available: {NATIVE_IMPORT_ERROR}")
    from . import native as module

    return module
