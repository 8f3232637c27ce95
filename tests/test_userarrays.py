"""nbvdata.core.userarrays: .npy files are read without unpickling anything and never with numpy's
advice to allow pickles; grids are checked by one function for nbvdata show and nbvtrain."""

import pickle
from pathlib import Path

import numpy as np
import pytest

from nbvdata.core.userarrays import GridError, NpyError, check_grids, read_npy


class Marks:
    """An object whose unpickling would create ``marker``."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return open, (str(self.marker), "w")


def test_plain_arrays_read_back_exactly(tmp_path, rng):
    for array in (rng.random((4, 3)), rng.random((2, 32, 32, 32)).astype(np.float32), np.arange(5, dtype=np.uint8)):
        np.save(tmp_path / "a.npy", array)
        read = read_npy(tmp_path / "a.npy")
        assert read.dtype == array.dtype and np.array_equal(read, array)


@pytest.mark.parametrize("kind, message", [
    ("missing", "no such file: check the path"),
    ("text", "not a numpy array file (.npy): write it with np.save"),
    ("a pickle of an array", "not a numpy array file (.npy)"),
    ("a pickle of an object", "not a numpy array file (.npy)"),
    ("an object array", "holds Python objects (a pickled object array); refused without unpickling it"),
    ("an npz", "holds several arrays (an .npz archive), not one: np.save one array"),
    ("cut short", "a .npy file, damaged or cut short"),
    ("a folder", "cannot be read"),
])
def test_anything_but_one_plain_array_is_named_and_never_unpickled(kind, message, tmp_path):
    path, marker = tmp_path / "a.npy", tmp_path / "ran"
    if kind == "text":
        path.write_text("0.5 0.5 0.5\n")
    elif kind == "a pickle of an array":
        path.write_bytes(pickle.dumps(np.zeros(3)))
    elif kind == "a pickle of an object":
        path.write_bytes(pickle.dumps(Marks(marker)))
    elif kind == "an object array":
        array = np.empty(1, dtype=object)
        array[0] = Marks(marker)
        np.save(path, array, allow_pickle=True)
    elif kind == "an npz":
        with path.open("wb") as handle:
            np.savez(handle, a=np.zeros(3))
    elif kind == "cut short":
        np.save(path, np.zeros((100, 3)))
        path.write_bytes(path.read_bytes()[:300])
    elif kind == "a folder":
        path.mkdir()
    with pytest.raises(NpyError) as refused:
        read_npy(path)
    text = str(refused.value)
    assert text.startswith(f"{path}: {message}"), text
    assert "allow_pickle" not in text and len(text.splitlines()) == 1
    assert not marker.exists()
    assert isinstance(refused.value, ValueError)


def test_a_robots_cloud_file_is_read_the_same_way(tmp_path):
    """nbvtrain plan's .npy clouds: the same refusal, never numpy's advice to allow pickles."""
    pytest.importorskip("torch")
    from nbvtrain.robot.sensordata import SensorDataError, read_cloud

    (tmp_path / "cloud.npy").write_text("1 2 3\n")
    with pytest.raises(SensorDataError) as refused:
        read_cloud(tmp_path / "cloud.npy")
    assert str(refused.value) == (f"{tmp_path / 'cloud.npy'}: not a numpy array file (.npy): write it with np.save "
                                  "(one (N, 3) float array)")


def test_check_grids_takes_one_or_a_batch_of_any_size():
    assert check_grids(np.full((8, 8, 8), 0.5), 8).shape == (1, 8, 8, 8)
    batch = check_grids(np.zeros((3, 16, 16, 16), dtype=np.float16), 16)
    assert batch.shape == (3, 16, 16, 16) and batch.dtype == np.float32
    with pytest.raises(GridError, match=r"grid has shape \(8, 8, 8\), expected \(16, 16, 16\) or \(B, 16, 16, 16\)"):
        check_grids(np.full((8, 8, 8), 0.5), 16)
