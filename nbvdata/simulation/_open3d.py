"""Import open3d on machines without a system libusb.

open3d's Linux wheel links ``libusb-1.0.so.0`` (for its RealSense support) but does not ship it,
so ``import open3d`` fails on a bare machine. The ``libusb-package`` wheel carries the library;
loading it with RTLD_GLOBAL first lets the dynamic linker resolve open3d's dependency.

nbvdata imports open3d only through this module. A script that imports open3d itself, before
nbvdata, must import this module first (``from nbvdata.simulation._open3d import open3d``): nothing runs
before an ``import open3d`` short of a .pth file or LD_LIBRARY_PATH, which a wheel should not set.
"""

from __future__ import annotations

import ctypes
import ctypes.util

HINT = ("nbvdata loads the libusb-1.0 that open3d links from the libusb-package wheel: pip install open3d "
        "libusb-package (or install the system's: apt install libusb-1.0-0); a script that imports open3d "
        "itself must first run `from nbvdata.simulation._open3d import open3d` (or `import nbvdata.simulation._open3d`)")


def _preload_libusb() -> None:
    if ctypes.util.find_library("usb-1.0"):
        return
    try:
        import libusb_package
    except ImportError:  # pragma: no cover - it is a declared dependency
        return
    path = libusb_package.get_library_path()
    if path is not None:
        ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)


_preload_libusb()

try:
    import open3d  # noqa: E402  (must follow the preload)
except ImportError as error:
    raise ImportError(f"cannot import open3d ({error}); {HINT}") from error

__all__ = ["open3d"]
