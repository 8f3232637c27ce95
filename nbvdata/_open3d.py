"""Import open3d on machines without a system libusb.

open3d's Linux wheel links ``libusb-1.0.so.0`` (for its RealSense support) but does not ship it,
so ``import open3d`` fails on a bare machine. The ``libusb-package`` wheel carries the library;
loading it with RTLD_GLOBAL first lets the dynamic linker resolve open3d's dependency.
"""

from __future__ import annotations

import ctypes
import ctypes.util


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

import open3d  # noqa: E402  (must follow the preload)

__all__ = ["open3d"]
