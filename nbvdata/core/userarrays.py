"""Arrays users hand in: ``.npy`` files read without unpickling anything, and occupancy grids
checked against the authors' encoding. ``nbvdata show``, ``nbvtrain predict`` (and its Python
API, ``nbvtrain.networks.predict.Predictor``) and ``nbvtrain plan``'s clouds all read through here."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nbvdata.core.errors import UserError

NPY_MAGIC = b"\x93NUMPY"
ZIP_MAGIC = b"PK\x03\x04"
HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
NOT_NPY = "not a numpy array file (.npy): write it with np.save"
ENCODING = "float occupancy probabilities in [0, 1], 0.5 = unknown (the authors' encoding)"


class NpyError(UserError):
    """A file that is not one plain numpy array; the message names the file and the fix."""


class GridError(UserError):
    """Input that is not occupancy grids in the authors' encoding; the message says what is wrong."""


def read_npy(path: Path, not_npy: str = NOT_NPY) -> np.ndarray:
    """The array in the ``.npy`` file at ``path``. NpyError when the file is missing, is no
    ``.npy`` file (text, an ``.npz`` archive, a pickle), is damaged, or holds Python objects:
    those are refused, never unpickled (``allow_pickle=False``). ``not_npy``: what the message
    says after the path of a file that is no ``.npy`` file at all (a caller that also reads other
    kinds of file names them)."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(len(NPY_MAGIC))
    except FileNotFoundError:
        raise NpyError(f"{path}: no such file: check the path") from None
    except OSError as error:
        raise NpyError(f"{path}: cannot be read ({error.strerror or type(error).__name__})") from None
    if head.startswith(ZIP_MAGIC):
        raise NpyError(f"{path}: holds several arrays (an .npz archive), not one: np.save one array")
    if head != NPY_MAGIC:
        raise NpyError(f"{path}: {not_npy}")
    try:
        return np.load(path, allow_pickle=False)
    except ValueError as error:
        if "allow_pickle" in str(error):  # numpy's advice to unpickle it: never given on
            raise NpyError(f"{path}: holds Python objects (a pickled object array); refused without unpickling "
                           "it: np.save an array of numbers") from None
        reason = str(error)
    except (OSError, EOFError) as error:
        reason = str(error) or type(error).__name__
    detail = f" ({reason.strip().splitlines()[0]})" if reason.strip() else ""
    raise NpyError(f"{path}: a .npy file, damaged or cut short{detail}: write it again with np.save")


def is_hdf5(path: Path) -> bool:
    """Whether the file at ``path`` starts as an HDF5 file does: its signature at byte 0, or after
    a user block (512, 1024, 2048, ... bytes). A damaged or truncated HDF5 file keeps it."""
    try:
        with open(path, "rb") as handle:
            size, offset = Path(path).stat().st_size, 0
            while offset + len(HDF5_MAGIC) <= size:
                handle.seek(offset)
                if handle.read(len(HDF5_MAGIC)) == HDF5_MAGIC:
                    return True
                offset = 512 if offset == 0 else 2 * offset
    except OSError:
        return False
    return False


def file_kind(path: Path) -> str:
    """What the file at ``path`` is, in a few words from its first bytes, for the message about a
    file that is not what was asked for: "an empty file", "a numpy array file (.npy)", "an .npz
    or other zip archive", "an HDF5 file", "a text file" or "other bytes"."""
    with open(path, "rb") as handle:
        head = handle.read(512)
    if not head:
        return "an empty file"
    if head.startswith(NPY_MAGIC):
        return "a numpy array file (.npy)"
    if head.startswith(ZIP_MAGIC):
        return "an .npz or other zip archive"
    if is_hdf5(path):
        return "an HDF5 file"
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError as error:  # a multi-byte letter may be cut at the end
        text = head[:error.start].decode("utf-8") if error.start >= len(head) - 3 else "\x00"
    return "a text file" if all(char.isprintable() or char in "\t\n\r\f" for char in text) else "other bytes"


def check_grids(grids: np.ndarray, size: int = 32) -> np.ndarray:
    """(n, n, n) or (B, n, n, n) float probabilities in [0, 1], n = ``size`` -> (B, n, n, n) float32.

    GridError for another shape, no grid at all (B = 0), an integer or boolean dtype, NaN or values
    outside [0, 1]."""
    array = np.asarray(grids)
    shape = (size,) * 3
    if array.ndim not in (3, 4) or array.shape[-3:] != shape:
        raise GridError(f"grid has shape {array.shape}, expected {shape} or (B, {', '.join(map(str, shape))})")
    if array.ndim == 4 and not len(array):
        raise GridError(f"holds no grid (shape {array.shape}): save at least one, (n, n, n) or (B, n, n, n) with B >= 1")
    if array.dtype.kind != "f":
        raise GridError(f"grid has dtype {array.dtype}, expected {ENCODING}")
    if array.size:
        nan = np.isnan(array)
        if nan.any():
            raise GridError(f"grid holds {int(nan.sum())} NaN values of {array.size}: expected {ENCODING}")
        low, high = float(array.min()), float(array.max())
        if low < 0 or high > 1:
            raise GridError(f"grid holds values in [{low:g}, {high:g}], outside [0, 1]: expected {ENCODING}")
    array = array.astype(np.float32, copy=False)
    return array[None] if array.ndim == 3 else array
