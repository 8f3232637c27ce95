"""The default scene is the paper's: the grid cube fitted to the object, the whole cube in view."""

import itertools
from pathlib import Path

import numpy as np
import pytest

from nbvdata.core.config import ConfigError, GridConfig, MeshConfig, SimConfig, load_config
from nbvdata.core.views import view_sphere
from nbvdata.simulation.episode import ViewCache
from nbvdata.simulation.grid import OccupancyGrid
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.shapes import BUILTIN_SHAPES, builtin_object

SMOKE = Path(__file__).resolve().parents[1] / "configs" / "smoke.yaml"


def test_the_fitted_cube_is_the_objects_largest_side_plus_half_a_voxel():
    config = SimConfig()
    assert config.grid.extent is None
    grid = OccupancyGrid(config.scene_grid)
    n, r = grid.size, grid.resolution
    for name in BUILTIN_SHAPES:
        low, high = builtin_object(name, config.mesh).mesh.bounds
        largest = int(np.argmax(high - low))
        # along the largest side the box lies a quarter voxel inside the cube's faces
        assert np.isclose(low[largest] - grid.origin, r / 4) and np.isclose(grid.origin + n * r - high[largest], r / 4)
        assert np.all(low >= grid.origin) and np.all(high <= grid.origin + n * r)


@pytest.mark.parametrize("name", ["step_block", "pill"])
def test_the_object_spans_the_fitted_grid_along_its_largest_side(name):
    config = SimConfig()
    obj = builtin_object(name, config.mesh)
    scene = Scene.build(obj, config, np.random.default_rng(0))
    cache, grid = ViewCache(scene), scene.new_grid()
    for view in range(0, len(scene.views), 5):
        grid.apply(cache.update(view))
    occupied = np.argwhere(grid.probabilities() > 0.5)
    low, high = obj.mesh.bounds
    largest = int(np.argmax(high - low))
    assert occupied[:, largest].min() == 0 and occupied[:, largest].max() == grid.size - 1


def test_every_candidate_view_of_the_default_scene_sees_the_whole_cube():
    config = SimConfig()
    half = config.scene_grid.extent / 2
    corners = np.array(list(itertools.product((-half, half), repeat=3)))
    views = view_sphere(config.views)
    camera = np.einsum("vij,vkj->vki", views.rotations, corners[None] - views.positions[:, None])
    assert np.all(camera[..., 2] > config.sensor.near)
    assert np.all(np.abs(camera[..., 0] / camera[..., 2]) <= np.tan(config.sensor.hfov / 2))
    assert np.all(np.abs(camera[..., 1] / camera[..., 2]) <= np.tan(config.sensor.vfov / 2))
    # ... and the size is the largest that does: 2 % more and some view cuts a corner off
    bigger = SimConfig(mesh=MeshConfig(object_size=config.mesh.object_size * 1.02)).scene_grid.extent / 2
    corners = np.array(list(itertools.product((-bigger, bigger), repeat=3)))
    camera = np.einsum("vij,vkj->vki", views.rotations, corners[None] - views.positions[:, None])
    assert np.any(np.abs(camera[..., 1] / camera[..., 2]) > np.tan(config.sensor.vfov / 2))


def test_the_fixed_cube_preset_is_the_old_scene():
    config = load_config(SimConfig, "configs/scene-fixed-cube.yaml")
    assert config.scene_grid.extent == 0.32 and config.scene_grid.resolution == 0.01
    assert config.mesh.object_size == 0.24


def test_an_unresolved_grid_says_how_to_resolve_it():
    with pytest.raises(ValueError, match="SimConfig.scene_grid"):
        GridConfig().resolution
    with pytest.raises(ConfigError, match="grid.extent=-1.0: must be > 0 metres, or null"):
        load_config(SimConfig, None, ["grid.extent=-1"])


def test_the_surface_voxels_hold_what_scans_mark_occupied(tmp_path):
    """state.surface: the mesh's surface voxels, once per shard; every voxel a noise-free scan marks
    occupied is one of them but for a sliver crossed at a voxel's face (under 2 %), and the surface
    reaches past what the scans saw (its hidden part: what a surface prior learns)."""
    from nbvdata.cli import main
    from nbvdata.schema.shards import Shard

    config = SimConfig()
    obj = builtin_object("mug", config.mesh)
    scene = Scene.build(obj, config, np.random.default_rng(0), threads=1)
    surface = scene.surface_voxels()
    assert surface.shape == (32, 32, 32) and surface.dtype == bool
    assert np.array_equal(surface, scene.surface_voxels())
    grid = scene.new_grid()
    for view in (0, 100, 250, 400):
        scene.integrate(grid, scene.scanner.scan(scene.views[view]))
    occupied = grid.probabilities() > 0.5
    assert (occupied & ~surface).sum() <= 0.02 * occupied.sum() and surface.sum() > 1.2 * occupied.sum()
    out = tmp_path / "shards"
    smoke = ["--config", str(SMOKE), "--runs-per-mesh", "1", "--no-progress", "--workers", "1"]
    assert main(["generate", "--out", str(out), "--set", "state.surface=true", *smoke]) == 0
    assert main(["generate", "--out", str(tmp_path / "plain"), *smoke]) == 0
    for path in sorted(out.glob("*.h5")):
        with Shard(path) as shard:
            stored = shard["surface"]
            occupied = shard.grids() > 0.5
            assert stored.dtype == bool and stored.shape == occupied.shape[1:]
            assert (occupied & ~stored).sum() <= 0.02 * occupied.sum()
    for path in sorted((tmp_path / "plain").glob("*.h5")):
        with Shard(path) as shard:
            assert not shard.has("surface")
