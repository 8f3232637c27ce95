"""Import LightGBM on machines without a system OpenMP runtime.

LightGBM's Linux wheel links ``libgomp.so.1`` (GCC's OpenMP runtime) but does not ship it, so
``import lightgbm`` fails on a slim image without the Debian package libgomp1 ("libgomp.so.1:
cannot open shared object file"). PyTorch's Linux wheels carry that very library
(``torch/lib/libgomp.so.1``, soname ``libgomp.so.1``), and torch is already a dependency of
nbvtrain: when the system has none, it is loaded with RTLD_GLOBAL before LightGBM, and the
dynamic linker resolves LightGBM's dependency with it (as ``nbvdata._open3d`` does for open3d's
libusb).

nbvtrain imports LightGBM only through this module (``from nbvtrain._lightgbm import lightgbm``).
"""

from __future__ import annotations

import ctypes
from pathlib import Path

HINT = ("LightGBM needs the OpenMP runtime libgomp.so.1: pip install lightgbm torch (nbvtrain loads torch's copy), "
        "or install the system's (apt install libgomp1)")


def _preload_libgomp() -> None:
    try:
        ctypes.CDLL("libgomp.so.1", mode=ctypes.RTLD_GLOBAL)  # the system's, where there is one
        return
    except OSError:
        pass
    try:
        import torch
    except ImportError:  # pragma: no cover - torch is nbvtrain's dependency
        return
    library = Path(torch.__file__).parent / "lib" / "libgomp.so.1"
    if library.is_file():
        ctypes.CDLL(str(library), mode=ctypes.RTLD_GLOBAL)


try:
    _preload_libgomp()
    import lightgbm  # noqa: E402  (must follow the preload)
except ImportError as error:
    raise ImportError(f"cannot import lightgbm ({error}); {HINT}") from error
except OSError as error:  # the library found but not loadable
    raise ImportError(f"cannot import lightgbm ({error}); {HINT}") from error

__all__ = ["lightgbm"]
