"""Import LightGBM on machines without a system OpenMP runtime.

LightGBM's Linux wheel links ``libgomp.so.1`` (GCC's OpenMP runtime) but does not ship it, so
``import lightgbm`` fails on a slim image without the Debian package libgomp1 ("libgomp.so.1:
cannot open shared object file"). PyTorch's Linux wheels carry that very library
(``torch/lib/libgomp.so.1``, soname ``libgomp.so.1``), and torch is already a dependency of
nbvtrain: when the system has none, it is loaded with RTLD_GLOBAL before LightGBM, and the
dynamic linker resolves LightGBM's dependency with it (as ``nbvdata.simulation._open3d`` does for open3d's
libusb).

nbvtrain imports LightGBM only through this module (``from nbvtrain.ranking._lightgbm import lightgbm``),
and reads a model file's LightGBM text only through ``load_booster``: LightGBM's parser aborts
the whole process on a damaged model text (SIGABRT or SIGSEGV, after hundreds of log lines), so
a model file carries the sha256 of its text (``TEXT_KEY``, ``text_digest``), checked before
LightGBM sees a byte, and LightGBM's own logging is off while it parses.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import json
import logging
import os
import sys
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

__all__ = ["lightgbm", "load_booster", "read_model_json", "text_digest", "TEXT_KEY"]

TEXT_KEY = "lightgbm_sha256"
"""The key under which a model file records the sha256 of its LightGBM text (``text_digest``)."""
_log = logging.getLogger(__name__)


def text_digest(text: str) -> str:
    """The sha256 of a LightGBM model text (its UTF-8 bytes)."""
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


@contextlib.contextmanager
def _stderr_closed():
    """The process's stderr (file descriptor 2) sent to /dev/null for the block, then restored."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


class _Quiet:
    """A logger for LightGBM that drops everything: its parser's warnings are no user's business."""

    def info(self, message: str) -> None:
        pass

    def warning(self, message: str) -> None:
        pass


def read_model_json(path: Path, what: str, fix: str, error: type[Exception]) -> dict | list:
    """The JSON content of a model file at ``path`` (``what`` it should be: "a ranker file", ...);
    ``error`` in one line naming it and ``fix`` when it is missing or no JSON."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: no such file, not {what}; {fix}")
    try:
        return json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as failure:
        raise error(f"{path}: not {what} (not JSON: {type(failure).__name__}); {fix}") from None


def load_booster(head: dict, path: Path, fix: str, error: type[Exception]) -> "lightgbm.Booster":
    """The LightGBM model of the model file ``head`` (its ``lightgbm`` text) read from ``path``;
    ``error`` (one line naming ``path`` and ``fix``) when the text is missing, does not match the
    sha256 the file records (``TEXT_KEY``: damaged) or does not parse. A file without the sha256
    (written before it existed) is parsed unchecked, with a warning."""
    text = head.get("lightgbm")
    if not isinstance(text, str):
        raise error(f"{path}: a model file without its LightGBM model; {fix}")
    recorded = head.get(TEXT_KEY)
    if recorded is None:
        _log.warning("%s: carries no checksum of its LightGBM model (written before nbvtrain recorded one): damage "
                     "to it goes undetected; fit it again to get one", path)
    elif text_digest(text) != recorded:
        raise error(f"{path}: damaged (its LightGBM model's sha256 is {text_digest(text)[:12]}..., the file records "
                    f"{str(recorded)[:12]}...): restore it from where it came, or {fix}")
    basic = lightgbm.basic
    previous = [getattr(basic, name, None) for name in ("_LOGGER", "_INFO_METHOD_NAME", "_WARNING_METHOD_NAME")]
    lightgbm.register_logger(_Quiet())
    try:
        with _stderr_closed():  # its fatal errors go to the process's stderr, not through the logger
            return lightgbm.Booster(model_str=text)
    except lightgbm.basic.LightGBMError as failure:
        raise error(f"{path}: its LightGBM model does not load ({str(failure).splitlines()[0][:120]}); {fix}") from None
    finally:
        if previous[0] is not None:  # whatever logger was registered before, as it was
            lightgbm.register_logger(*previous)
