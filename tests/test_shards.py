"""The shard format: exact round trips, the grid palette, atomic writes, clear errors."""

import h5py
import numpy as np
import pytest

from nbvdata.core.config import SimConfig, load_config
from nbvdata.core.logodds import probability
from nbvdata.core.views import view_sphere
from nbvdata.schema.shards import PER_SAMPLE, GridPalette, Shard, ShardError, write_shard
from nbvdata.simulation.grid import OccupancyGrid
from nbvdata.simulation.sensor import MeshScanner
from nbvdata.simulation.shapes import builtin_object


def _arrays(rng, count: int, views: int = 9, n: int = 32) -> dict[str, np.ndarray]:
    arrays = {}
    for name, (dtype, shape) in PER_SAMPLE.items():
        full = (count,) + shape(views, n)
        if name == "grids":
            arrays[name] = rng.integers(0, 3, full, dtype=np.uint8)
        elif name == "mesh_id":
            arrays[name] = np.full(count, b"ab" * 32, dtype="S64")
        elif np.issubdtype(dtype, np.integer):  # view indices and counts: within the views, as a reader checks
            arrays[name] = rng.integers(0, views, full).astype(dtype)
        else:  # probabilities, fractions, coordinates: in [0, 1)
            arrays[name] = (rng.random(full) < 0.5) if dtype is bool else rng.random(full).astype(dtype)
    arrays["grid_palette"] = np.array([0.5, 0.12, 0.97], dtype=np.float32)
    arrays["view_positions"] = rng.random((views, 3))
    arrays["view_poses"] = rng.random((views, 6))
    return arrays


ATTRS = {"package_version": "0.1.0", "config": "grid:\n  size: 32\n", "meshes": '[{"id": "ab"}]',
         "samples": 0, "runs": np.array([0, 4])}


@pytest.mark.parametrize("count", [0, 1, 5])
def test_write_read_round_trip_is_exact_and_atomic(tmp_path, rng, count):
    arrays = _arrays(rng, count)
    path = tmp_path / "a.h5"
    write_shard(path, arrays, dict(ATTRS, samples=count))
    assert [p.name for p in tmp_path.iterdir()] == ["a.h5"]  # no .partial left behind
    with Shard(path) as shard:
        assert len(shard) == count and shard.info.runs == (0, 4) and shard.info.config == {"grid": {"size": 32}}
        for name, array in arrays.items():
            stored = shard[name]
            assert stored.dtype == array.dtype and np.array_equal(stored, array), name
        assert np.array_equal(shard.grids(), arrays["grid_palette"][arrays["grids"]])
        if count:
            assert shard.file["gains"].chunks == (1, 9) and shard.file["grids"].compression == "gzip"
    write_shard(tmp_path / "b.h5", arrays, dict(ATTRS, samples=count))
    assert (tmp_path / "a.h5").read_bytes() == (tmp_path / "b.h5").read_bytes()  # no timestamps


def test_palette_recovers_the_grid_probabilities_exactly(rng):
    config = load_config(SimConfig, None, ["sensor.width=88", "sensor.height=72"])
    obj = builtin_object("mug", config.mesh)
    scanner, views = MeshScanner(obj.mesh, config.sensor), view_sphere(config.views)
    grid, palette = OccupancyGrid(config.scene_grid), GridPalette()
    for view in (0, 200, 400, 200):
        grid.integrate(scanner.scan(views[view]), config.sensor.far)
        codes = palette.encode(grid.log_odds)
        decoded = palette.probabilities()[codes]
        assert np.array_equal(decoded, grid.probabilities())
        assert np.all(decoded[grid.log_odds == 0] == 0.5) and np.all(codes[grid.log_odds == 0] == 0)
    assert 3 < len(palette) < 256


def test_palette_codes_values_in_order_of_first_appearance(rng):
    """Against the plain rule (a dict; a grid's new values get codes in ascending order): the
    same codes, grid after grid, with values repeating, new ones arriving late, -0.0 as 0.0."""
    pool = np.array([0.0, -0.4, 0.85, 1.7, -0.8, 2.2, -2.1, 3.5], dtype=np.float32)
    codes_of: dict[float, int] = {0.0: 0}
    palette = GridPalette()
    for count in (2, 2, 5, 3, 8, 8):
        grid = rng.choice(pool[:count], size=(8, 8, 8))
        grid[0, 0, 0] = -0.0
        for value in sorted(set(grid.ravel().tolist())):
            codes_of.setdefault(value, len(codes_of))
        expected = np.vectorize(codes_of.__getitem__)(grid)
        assert np.array_equal(palette.encode(grid), expected)
    assert len(palette) == len(pool)


def test_palette_grows_past_256_values(rng):
    palette = GridPalette()
    log_odds = np.linspace(-2, 3.5, 32 ** 3, dtype=np.float32).reshape(32, 32, 32)
    codes = palette.encode(log_odds)
    assert codes.max() > 255 and len(palette) == len(np.unique(log_odds)) + 1
    assert np.array_equal(palette.probabilities()[codes], probability(log_odds))


def test_broken_shards_raise_a_shard_error_naming_the_file_and_the_fix(tmp_path, rng):
    path = tmp_path / "a.h5"
    write_shard(path, _arrays(rng, 4), dict(ATTRS, samples=4))
    data = path.read_bytes()

    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(ShardError, match=r"truncated\.h5: not a readable HDF5 file .*delete it"):
        Shard(truncated)

    with pytest.raises(ShardError, match="no such shard"):
        Shard(tmp_path / "missing.h5")

    with h5py.File(tmp_path / "foreign.h5", "w") as f:
        f["x"] = 1
    with pytest.raises(ShardError, match="not an nbvdata shard"):
        Shard(tmp_path / "foreign.h5")

    incomplete = tmp_path / "incomplete.h5"
    incomplete.write_bytes(data)
    with h5py.File(incomplete, "a") as f:
        del f["gains"]
    with pytest.raises(ShardError, match="missing gains"):
        Shard(incomplete)

    with h5py.File(incomplete, "a") as f:
        f.attrs["schema_version"] = 99
    with pytest.raises(ShardError, match="schema version 99"):
        Shard(incomplete)


def test_write_refuses_inconsistent_arrays(tmp_path, rng):
    arrays = _arrays(rng, 3)
    arrays["run"] = arrays["run"][:2]
    with pytest.raises(ValueError, match="run has 2 rows"):
        write_shard(tmp_path / "a.h5", arrays, dict(ATTRS, samples=3))
    assert list(tmp_path.iterdir()) == []


def test_optional_datasets_may_be_absent_but_required_ones_may_not(tmp_path, rng):
    arrays = _arrays(rng, 3)
    for name in ("gains", "overlaps", "coverage", "mesh_id", "last_view", "seed", "view_poses"):
        del arrays[name]
    write_shard(tmp_path / "a.h5", arrays, dict(ATTRS, samples=3, source="test import"))
    with Shard(tmp_path / "a.h5") as shard:
        assert shard.info.source == "test import"
        assert not shard.has("gains") and shard.has("nbv_position")
        assert np.array_equal(shard["nbv_index"], arrays["nbv_index"])
    del arrays["nbv_position"]
    with pytest.raises(ValueError, match="nbv_position"):
        write_shard(tmp_path / "b.h5", arrays, dict(ATTRS, samples=3))
    assert not (tmp_path / "b.h5").exists()


def test_probability_palette_keeps_unknown_at_code_zero():
    palette = GridPalette(log_odds=False)
    codes = palette.encode(np.array([[0.7, 0.5], [0.4, 0.7]]))
    assert codes[0, 1] == 0 and codes[0, 0] == codes[1, 1] != codes[1, 0]
    assert np.array_equal(palette.probabilities()[codes], np.array([[0.7, 0.5], [0.4, 0.7]], dtype=np.float32))
