"""The one place that imports open3d (lazily, so grid-only pipelines never pay for it)."""

from __future__ import annotations

import functools
from types import ModuleType


@functools.cache
def open3d() -> ModuleType:
    """Import open3d once, silence its logging, and turn an ImportError into a one-line RuntimeError."""
    try:
        import open3d as o3d
    except ImportError as exc:  # e.g. the GPU `open3d` wheel without the system libusb-1.0
        if isinstance(exc.__cause__, KeyboardInterrupt):  # Ctrl-C or SIGTERM during its (pybind11) init
            raise exc.__cause__ from None
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        hint = (
            " (the `open3d` wheel needs the system library libusb-1.0; install `open3d-cpu==0.20.0` instead)"
            if "libusb" in msg
            else " (install `open3d-cpu==0.20.0`)"
        )
        raise RuntimeError(f"sensors: cannot import open3d: {msg}{hint}") from None
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    return o3d
