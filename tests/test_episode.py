"""Labelled reconstruction runs: cached scans equal live ones, labels follow the oracle's rule, and
stay exact when runs explore."""

import numpy as np
import pytest

from nbvdata.core.config import SimConfig, load_config
from nbvdata.simulation.episode import (EXPLORE, NO_MOVE, ORACLE, Mover, Reconstruction, ViewCache, run_reconstruction,
                                        run_seed, scene_rng, start_view)
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.sensor import MeshScanner
from nbvdata.simulation.shapes import builtin_object

SMOKE = ["views.count=60", "sensor.width=44", "sensor.height=36", "coverage.points=2000"]


@pytest.fixture(scope="module")
def scene() -> Scene:
    config = load_config(SimConfig, None, SMOKE + ["episode.max_scans=6"])
    obj = builtin_object("mug", config.mesh)
    return Scene.build(obj, config, scene_rng(0, obj.mesh_id))


def test_cached_scans_give_the_same_state_as_live_scans(scene, rng):
    cached = Reconstruction(scene, ViewCache(scene), rng)
    live = Reconstruction(scene, None, rng)
    for view in rng.choice(len(scene.views), size=5, replace=False):
        cached.scan(int(view))
        live.scan(int(view))
        assert np.array_equal(cached.grid.log_odds, live.grid.log_odds)
        assert np.array_equal(cached.covered, live.covered)
    assert np.any(cached.grid.log_odds != 0)


def test_a_run_records_oracle_labels_and_monotone_coverage(scene):
    config = scene.config
    record = run_reconstruction(scene, 3, np.random.default_rng(0), ViewCache(scene))
    assert 1 <= len(record) <= config.episode.max_scans
    assert record.last_view[0] == 3 and record.last_view[1:] == record.nbv_index[:-1]
    coverage = np.array(record.coverage)
    assert np.all(coverage[:, 1] > coverage[:, 0])  # the NBV always adds surface
    assert np.allclose(coverage[1:, 0], coverage[:-1, 1])  # and the next state is exactly that
    for nbv, gains, overlaps in zip(record.nbv_index, record.gains, record.overlaps):
        valid = overlaps >= config.oracle.min_overlap
        assert valid[nbv] and gains[nbv] == gains[valid].max()
        assert gains[nbv] >= config.episode.min_gain
    steps_changed = [np.count_nonzero(a != b) for a, b in zip(record.log_odds, record.log_odds[1:])]
    assert all(changed > 0 for changed in steps_changed)


def test_a_run_stops_when_no_valid_view_adds_enough(scene):
    config = load_config(SimConfig, None, SMOKE + ["episode.max_scans=50", "episode.min_gain=0.05"])
    strict = Scene(config, scene.object, scene.views, scene.scanner, scene.coverage, scene.oracle)
    record = run_reconstruction(strict, 0, np.random.default_rng(0), ViewCache(strict))
    assert len(record) < 50
    covered = np.bitwise_or.reduce(strict.oracle.visible[[0] + record.nbv_index], axis=0)
    last = strict.oracle.score(covered)  # the state after the last labelled NBV was scanned
    assert last.best(config.oracle.min_overlap, config.episode.min_gain) is None


def test_runs_are_seeded_by_seed_mesh_and_run():
    mesh = "ab" * 32
    assert start_view(0, mesh, 500, 7) == start_view(0, mesh, 500, 7)
    starts = [start_view(0, mesh, 500, run) for run in range(500)]
    assert sorted(starts) == list(range(500))  # the first V runs start from distinct views
    assert run_seed(0, mesh, 1) != run_seed(0, mesh, 2) != run_seed(1, mesh, 2)
    assert starts[:10] != [start_view(0, "cd" * 32, 500, run) for run in range(10)]
    assert starts[:10] != [start_view(1, mesh, 500, run) for run in range(10)]


def test_noisy_runs_are_live_and_reproducible(scene):
    config = load_config(SimConfig, None, SMOKE + ["episode.max_scans=4", "sensor.noise_std=0.002"])
    noisy = Scene(config, scene.object, scene.views, MeshScanner(scene.object.mesh, config.sensor),
                  scene.coverage, scene.oracle)
    a = run_reconstruction(noisy, 5, np.random.default_rng(11), None)
    b = run_reconstruction(noisy, 5, np.random.default_rng(11), None)
    c = run_reconstruction(noisy, 5, np.random.default_rng(12), None)
    assert all(np.array_equal(x, y) for x, y in zip(a.log_odds, b.log_odds))
    assert any(not np.array_equal(x, y) for x, y in zip(a.log_odds, c.log_odds))


# ---------------------------------------------------------------------------------------------
# Runs off the oracle's path: exploration moves (episode.explore)


def _live_views(scene: Scene) -> np.ndarray:
    """(V, P) bool: what a live scan from each candidate view covers, without the oracle's bit
    matrix or the view cache: the reference the labels are checked against."""
    rng = np.random.default_rng(0)
    return np.array([scene.coverage.covered_by(scene.scanner.scan(scene.views[v], rng).hit_points)
                     for v in range(len(scene.views))])


def _check_exact_labels(scene: Scene, record, start: int, seen: np.ndarray) -> None:
    """Replay a run through the views it actually scanned (live scans) and check that every
    recorded state is that state, labelled with the best valid view by an independent count."""
    config = scene.config
    counts, observable = seen.sum(axis=1), seen.any(axis=0).sum()
    covered = seen[start].copy()
    live = Reconstruction(scene, None, np.random.default_rng(0))
    live.scan_pose(scene.views[start])
    for i in range(len(record)):
        assert np.array_equal(record.log_odds[i], live.grid.log_odds)
        new = (seen & ~covered).sum(axis=1)
        overlaps = np.where(counts > 0, (counts - new) / np.maximum(counts, 1), 0.0)
        gains = new / observable
        valid = (overlaps >= config.oracle.min_overlap) & (new > 0) & (gains >= config.episode.min_gain)
        assert record.nbv_index[i] == int(np.argmax(np.where(valid, gains, -1.0)))
        assert np.array_equal(record.gains[i], gains.astype(np.float32))
        assert np.array_equal(record.overlaps[i], overlaps.astype(np.float32))
        if record.move[i] == NO_MOVE:
            assert i == len(record) - 1 and record.next_view[i] == -1 and np.isnan(record.next_pose[i]).all()
            break
        view = record.next_view[i]
        assert np.array_equal(record.next_pose[i], scene.views[view].xyzypr)
        if i + 1 < len(record):
            assert record.last_view[i + 1] == view
        covered |= seen[view]
        live.scan_pose(scene.views[view])


def test_without_exploration_a_run_draws_nothing_and_moves_to_its_labels(scene):
    mesh_id = scene.object.mesh_id
    plain = run_reconstruction(scene, 3, np.random.default_rng(0), ViewCache(scene))
    mover = Mover.for_run(0.0, None, 0.0, 0, mesh_id, 0)
    state = mover.rng.bit_generator.state
    same = run_reconstruction(scene, 3, np.random.default_rng(0), ViewCache(scene), mover)
    assert mover.rng.bit_generator.state == state  # not one number drawn
    for name in ("nbv_index", "last_view", "coverage", "move", "next_view"):
        assert getattr(plain, name) == getattr(same, name)
    assert all(np.array_equal(a, b) for a, b in zip(plain.log_odds, same.log_odds))
    assert set(plain.move[:-1]) == {ORACLE} and plain.next_view[:-1] == plain.nbv_index[:-1]


def test_exploring_runs_keep_exact_labels(scene):
    seen = _live_views(scene)
    mesh_id = scene.object.mesh_id
    explored = 0
    for run in range(6):
        start = start_view(0, mesh_id, len(scene.views), run)
        mover = Mover.for_run(0.5, None, 0.0, 0, mesh_id, run)
        record = run_reconstruction(scene, start, np.random.default_rng(run), ViewCache(scene), mover)
        _check_exact_labels(scene, record, start, seen)
        moves = np.array(record.move)
        assert set(moves[:-1]) <= {ORACLE, EXPLORE}
        for i in np.flatnonzero(moves == EXPLORE):
            assert record.overlaps[i][record.next_view[i]] >= scene.config.oracle.min_overlap
        explored += int((moves == EXPLORE).sum())
    assert explored > 0


def test_the_share_of_moves_off_the_label_is_close_to_epsilon_on_a_long_run(scene):
    config = load_config(SimConfig, None, SMOKE + ["episode.max_scans=12", "episode.min_gain=0"])
    long = Scene(config, scene.object, scene.views, scene.scanner, scene.coverage, scene.oracle)
    epsilon, mesh_id, cache = 0.3, scene.object.mesh_id, ViewCache(long)
    moves, off_label, chance_on_label = [], [], []
    for run in range(60):
        start = start_view(0, mesh_id, len(long.views), run)
        record = run_reconstruction(long, start, np.random.default_rng(run), cache,
                                    Mover.for_run(epsilon, None, 0.0, 0, mesh_id, run))
        for i, move in enumerate(record.move):
            if move == NO_MOVE:
                continue
            moves.append(move)
            off_label.append(record.next_view[i] != record.nbv_index[i])
            chance_on_label.append(1 / np.count_nonzero(record.overlaps[i] >= config.oracle.min_overlap))
    moves, off_label = np.array(moves), np.array(off_label)
    count = len(moves)
    assert count > 500
    assert not off_label[moves == ORACLE].any()  # an oracle move is the label, always
    sigma = np.sqrt(epsilon * (1 - epsilon) / count)
    assert abs((moves == EXPLORE).mean() - epsilon) < 4 * sigma
    expected = epsilon * (1 - np.mean(chance_on_label))  # a random valid view may be the label itself
    assert abs(off_label.mean() - expected) < 4 * sigma


def test_the_moves_are_seeded_by_seed_mesh_and_run(scene):
    mesh_id = scene.object.mesh_id
    draws = lambda seed, run: Mover.for_run(0.5, None, 0.0, seed, mesh_id, run).rng.random(8)  # noqa: E731
    assert np.array_equal(draws(0, 1), draws(0, 1))
    assert not np.array_equal(draws(0, 1), draws(0, 2)) and not np.array_equal(draws(0, 1), draws(1, 1))
    noise = np.random.default_rng(run_seed(0, mesh_id, 1)).random(8)
    assert not np.array_equal(draws(0, 1), noise)  # its own stream, not the range noise's


def test_exploration_draws_do_not_shift_the_range_noise(scene):
    """A noisy exploring run replayed through the views it took, with the run's noise generator
    alone, gives the same states: the moves draw from their own stream."""
    config = load_config(SimConfig, None, SMOKE + ["episode.max_scans=5", "sensor.noise_std=0.002"])
    noisy = Scene(config, scene.object, scene.views, MeshScanner(scene.object.mesh, config.sensor),
                  scene.coverage, scene.oracle)
    mover = Mover.for_run(0.5, None, 0.0, 0, scene.object.mesh_id, 0)
    record = run_reconstruction(noisy, 5, np.random.default_rng(11), None, mover)
    assert EXPLORE in record.move and ORACLE in record.move
    replay = Reconstruction(noisy, None, np.random.default_rng(11))
    replay.scan(5)
    for i in range(len(record)):
        assert np.array_equal(record.log_odds[i], replay.grid.log_odds)
        if record.move[i] == NO_MOVE:
            break
        replay.scan(record.next_view[i])
