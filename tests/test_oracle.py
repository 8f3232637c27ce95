"""The exhaustive search: packed bit sets, the NBV rule, and exact agreement with re-simulation."""

import numpy as np
import pytest
from conftest import MESHES, need

from nbvdata.core.config import SimConfig, load_config
from nbvdata.simulation.coverage import SurfaceCoverage
from nbvdata.simulation.mesh import load_mesh
from nbvdata.simulation.oracle import Scores, ViewOracle, pack_bits, popcount, unpack_bits
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.sensor import MeshScanner


@pytest.mark.parametrize("points", [1, 63, 64, 65, 1000])
def test_pack_unpack_round_trip_and_popcount(points, rng):
    mask = rng.random((7, points)) < 0.3
    bits = pack_bits(mask)
    assert bits.dtype == np.uint64 and bits.shape == (7, -(-points // 64))
    assert np.array_equal(unpack_bits(bits, points), mask)
    assert popcount(bits) == mask.sum()
    assert popcount(bits[3]) == mask[3].sum()


def test_best_takes_the_largest_valid_gain_and_the_first_of_ties():
    new = np.array([5, 9, 9, 9, 0], dtype=np.int32)
    scores = Scores(new=new, seen=np.zeros(5, np.int32), gains=new / 10.0,
                    overlaps=np.array([0.5, 0.1, 0.3, 0.3, 0.9]))
    assert scores.best(min_overlap=0.2) == 2  # view 1 overlaps too little; 2 and 3 tie
    assert scores.best(min_overlap=0.6) is None  # only view 4, which adds nothing
    assert scores.best(min_overlap=0.2, min_gain=0.95) is None


def test_scores_on_a_hand_made_bit_matrix():
    visible = np.array([[1, 1, 0, 0, 0],
                        [0, 1, 1, 1, 0],
                        [0, 0, 0, 0, 0]], dtype=bool)
    oracle = ViewOracle(visible)
    assert oracle.observable_count == 4
    scores = oracle.score(pack_bits(np.array([1, 0, 0, 0, 0], dtype=bool)))
    assert scores.new.tolist() == [1, 3, 0] and scores.seen.tolist() == [1, 0, 0]
    assert np.allclose(scores.gains, [0.25, 0.75, 0.0]) and np.allclose(scores.overlaps, [0.5, 0.0, 0.0])
    assert scores.best(min_overlap=0.2) == 0  # view 1 gains more but shares nothing


def _resimulated_scores(mesh, config: SimConfig, views, seed: int, visited):
    """Gain and overlap of every candidate computed the slow way, from fresh scans only:
    (new, seen, gains, overlaps) with gains as differences of ``SurfaceCoverage.coverage``."""
    scanner = MeshScanner(mesh, config.sensor)
    coverage = SurfaceCoverage(mesh, config.coverage, np.random.default_rng(seed))
    seen_by = [coverage.covered_by(scanner.scan(views[v]).hit_points) for v in range(len(views))]
    coverage.observable = np.any(seen_by, axis=0)
    covered = coverage.covered_by_scans(scanner.scan(views[v]) for v in visited)
    before = coverage.coverage(covered)[1]
    new = np.array([np.count_nonzero(o & ~covered) for o in seen_by])
    seen = np.array([np.count_nonzero(o & covered) for o in seen_by])
    gains = np.array([coverage.coverage(covered | o)[1] - before for o in seen_by])
    sizes = np.array([np.count_nonzero(o) for o in seen_by])
    overlaps = np.divide(seen, sizes, out=np.zeros(len(sizes)), where=sizes > 0)
    return new, seen, gains, overlaps


@pytest.mark.parametrize("name", ["toy_duck__trimesh_khronos.ply", "cup_mug__ycb_urdfmodels.obj"])
def test_exhaustive_search_equals_resimulating_every_candidate(name, rng):
    path = need(MESHES / "train" / name)
    config = load_config(SimConfig, None, ["views.count=120", "sensor.width=88", "sensor.height=72",
                                           "coverage.points=4000"])
    obj = load_mesh(path, config.mesh)
    scene = Scene.build(obj, config, np.random.default_rng(7))
    oracle = scene.oracle
    visited = [int(rng.integers(len(scene.views)))]
    for _ in range(3):  # states after 1, 2 and 3 scans along the oracle's own choices
        covered = np.zeros(oracle.visible.shape[1], dtype=np.uint64)
        for v in visited:
            covered |= oracle.visible[v]
        scores = oracle.score(covered)
        new, seen, gains, overlaps = _resimulated_scores(obj.mesh, config, scene.views, 7, visited)
        assert np.array_equal(scores.new, new) and np.array_equal(scores.seen, seen)
        assert np.allclose(scores.gains, gains, rtol=0, atol=1e-12)
        assert np.array_equal(scores.overlaps, overlaps)
        assert new.max() > 0 and seen.max() > 0  # the state is a real test: views differ
        valid = overlaps >= config.oracle.min_overlap
        nbv = scores.best(config.oracle.min_overlap)
        assert nbv is not None and valid[nbv] and new[nbv] == new[valid].max()
        visited.append(nbv)
