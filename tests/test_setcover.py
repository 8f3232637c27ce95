"""Set-cover labels: agreement with brute force, the reuse rules, canonical sets, work limits."""

import hashlib
import itertools
import os
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from conftest import about

from nbvdata.cli import main
from nbvdata.core.config import SimConfig, load_config
from nbvdata.core.views import view_sphere
from nbvdata.datasets.generate import generate
from nbvdata.schema.shards import COVER, Shard
from nbvdata.simulation import setcover
from nbvdata.simulation.episode import scene_rng
from nbvdata.simulation.oracle import ViewOracle, pack_bits, popcount
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.setcover import (Cover, _candidates, _lexicographic_cover, _minimal_rows, greedy_cover,
                                         next_cover, solve_cover)
from nbvdata.simulation.sources import builtin_sources
from nbvtrain.evaluation.evaluate import FLOOR_COLUMNS, evaluate, scans_table, scans_to, write_outputs
from nbvtrain.planners import SetCoverPlanner, build_planners


def _instance(rng, views: int, points: int, density: float) -> ViewOracle:
    visible = rng.random((views, points)) < density
    visible[:, rng.random(points) < 0.1] = False  # some points no view sees: not observable
    return ViewOracle(visible)


def _brute_force(oracle: ViewOracle, covered: np.ndarray) -> tuple[int, tuple[int, ...]]:
    """(optimum, lexicographically smallest optimal cover) by trying every set, smallest first."""
    remaining = oracle.observable & ~covered
    if popcount(remaining) == 0:
        return 0, ()
    for size in range(1, len(oracle) + 1):
        for views in itertools.combinations(range(len(oracle)), size):  # lexicographic order
            if popcount(remaining & ~np.bitwise_or.reduce(oracle.visible[list(views)], axis=0)) == 0:
                return size, views
    raise AssertionError("the observable points always have a cover")


def _covers(oracle: ViewOracle, covered: np.ndarray, views) -> bool:
    union = covered.copy()
    for v in views:
        union |= oracle.visible[v]
    return popcount(oracle.observable & ~union) == 0


@pytest.mark.parametrize("seed", range(40))
def test_optimum_and_canonical_set_equal_brute_force(seed):
    rng = np.random.default_rng(seed)
    oracle = _instance(rng, views=int(rng.integers(4, 15)), points=int(rng.integers(10, 80)),
                       density=float(rng.uniform(0.08, 0.4)))
    scanned = rng.choice(len(oracle), size=int(rng.integers(0, 3)), replace=False)
    covered = np.bitwise_or.reduce(oracle.visible[scanned], axis=0) if len(scanned) else np.zeros_like(oracle.observable)
    cover = solve_cover(oracle, covered, node_limit=10**6)
    optimum, smallest = _brute_force(oracle, covered)
    assert _covers(oracle, covered, cover.views)
    assert cover.proved and cover.size == optimum and cover.bound == optimum
    assert cover.bound <= cover.size <= cover.greedy == len(greedy_cover(oracle, covered))
    # from scratch: the greedy cover when it is optimal, else the lexicographically smallest optimal set
    greedy = greedy_cover(oracle, covered)
    assert cover.views == (tuple(sorted(greedy)) if len(greedy) == optimum else smallest)


@pytest.mark.parametrize("seed", range(40))
def test_constraint_generation_from_a_few_rows_gives_the_same_labels(seed, monkeypatch):
    """Solved from 2 rows, adding 1 uncovered row a round (instead of hundreds), every program is
    a relaxation until its cover covers all rows: the labels stay those of the whole program."""
    rng = np.random.default_rng(seed)
    oracle = _instance(rng, views=int(rng.integers(4, 15)), points=int(rng.integers(10, 80)),
                       density=float(rng.uniform(0.08, 0.4)))
    covered = np.zeros_like(oracle.observable)
    whole = solve_cover(oracle, covered, node_limit=10**6)
    monkeypatch.setattr(setcover, "SEARCH_NODES", 0)  # the MILP alone
    monkeypatch.setattr(setcover, "ROWS_SEED", 2)
    monkeypatch.setattr(setcover, "ROWS_ADDED", 1)
    assert solve_cover(oracle, covered, node_limit=10**6) == whole


@pytest.mark.parametrize("seed", range(20))
def test_run_labels_follow_the_reuse_rules_and_stay_optimal(seed):
    """Along a run of random moves, every label is an optimal cover, its size drops by at most one
    per scan, and when the view scanned was in the previous cover the rest of it is the label."""
    rng = np.random.default_rng(100 + seed)
    oracle = _instance(rng, views=int(rng.integers(6, 14)), points=60, density=0.15)
    covered = np.zeros_like(oracle.observable)
    previous = solve_cover(oracle, covered, 10**6)
    assert previous.size == _brute_force(oracle, covered)[0]
    for view in rng.permutation(len(oracle))[:6]:
        covered = covered | oracle.visible[view]
        label = next_cover(oracle, covered, previous, int(view), 10**6)
        optimum = _brute_force(oracle, covered)[0]
        assert _covers(oracle, covered, label.views) and label.proved and label.size == optimum
        assert previous.size - 1 <= label.size <= previous.size
        if view in previous.views:
            assert label.views == tuple(v for v in previous.views if v != view)
        previous = label


def test_a_scan_that_is_no_candidate_gives_no_lower_bound():
    """A live scan may cover points of several views: the label is still optimal, found without
    the opt - 1 bound (which would be wrong here: two views' points go at once)."""
    visible = np.zeros((4, 4), dtype=bool)
    visible[0, 0] = visible[1, 1] = visible[2, 2] = visible[3, 3] = True
    oracle = ViewOracle(visible)
    previous = solve_cover(oracle, np.zeros_like(oracle.observable), 10)
    assert previous.size == 4
    covered = pack_bits(np.array([True, True, False, False]))
    label = next_cover(oracle, covered, previous, None, 10)
    assert label.views == (2, 3) and label.proved


def test_reductions_keep_the_minimal_covering_sets_and_the_undominated_views():
    visible = np.array([[1, 1, 1, 0],   # view 0 sees points 0-2
                        [1, 0, 0, 0],   # view 1: a subset of view 0's rows
                        [0, 1, 1, 1],
                        [0, 0, 0, 1]], dtype=bool)
    oracle = ViewOracle(visible)
    rows = _minimal_rows(oracle, oracle.observable)
    # point covering sets: p0 {0, 1}, p1 {0, 2}, p2 {0, 2}, p3 {2, 3}: p1 and p2 merge, none holds another
    assert sorted(tuple(np.flatnonzero(r)) for r in rows) == [(0, 1), (0, 2), (2, 3)]
    # view 1 covers only row {0, 1}, which view 0 covers too; view 3 only row {2, 3}, as view 2
    assert _candidates(rows).tolist() == [True, False, True, False]


@pytest.mark.parametrize("seed", range(30))
def test_the_exact_search_and_the_milp_give_the_same_labels(seed, monkeypatch):
    rng = np.random.default_rng(300 + seed)
    oracle = _instance(rng, views=int(rng.integers(8, 30)), points=int(rng.integers(40, 200)),
                       density=float(rng.uniform(0.1, 0.3)))
    covered = np.zeros_like(oracle.observable)
    searched = solve_cover(oracle, covered, node_limit=10**4)
    monkeypatch.setattr(setcover, "SEARCH_NODES", 0)
    assert solve_cover(oracle, covered, node_limit=10**4) == searched and searched.proved


def test_the_exact_search_proves_what_it_finds_and_gives_up_within_its_budget():
    """Five views, each covering all but one of five rows: no single view covers, two do; with one
    branch the search cannot tell."""
    rows = ~np.eye(5, dtype=bool)
    sub = rows[np.argsort(rows.sum(axis=1), kind="stable")]
    packed, covering = setcover.pack_bits(sub.T), np.nonzero(sub)[1].astype(np.int64)
    starts = np.concatenate([[0], np.cumsum(sub.sum(axis=1))]).astype(np.int64)
    assert setcover._search(packed, covering, starts, 1, 100)[0] == -1  # proved: none of one view
    size, chosen, used, finished = setcover._search(packed, covering, starts, 2, 100)
    assert finished and size == 2 and rows[:, chosen[:2]].any(axis=1).all()
    assert setcover._search(packed, covering, starts, 1, 1)[3] is False


def _hard_instance(monkeypatch) -> tuple[ViewOracle, np.ndarray]:
    """An instance whose optimum takes HiGHS more than one branch-and-bound node (and is below
    greedy), solved by the MILP alone (the exact search would prove it at once)."""
    monkeypatch.setattr(setcover, "SEARCH_NODES", 0)
    oracle = _instance(np.random.default_rng(0), views=30, points=200, density=0.25)
    return oracle, np.zeros_like(oracle.observable)


def test_a_state_that_hits_the_node_limit_keeps_a_cover_and_a_true_bound(monkeypatch):
    """With one node the solver proves little: the label is a cover with a lower bound no larger
    than the optimum, never an error; with enough nodes the same state is proved optimal."""
    oracle, covered = _hard_instance(monkeypatch)
    cover = solve_cover(oracle, covered, node_limit=1)
    whole = solve_cover(oracle, covered, node_limit=10**4)
    assert whole.proved and whole.size < whole.greedy
    assert not cover.proved and _covers(oracle, covered, cover.views)
    assert 1 <= cover.bound <= whole.size <= cover.size <= cover.greedy


def test_labels_do_not_depend_on_the_clock(monkeypatch):
    """A clock that runs a thousand times fast - a busy machine, as a wall-clock limit sees it -
    changes no label, proved or not: the limit is a count of nodes."""
    oracle, covered = _hard_instance(monkeypatch)
    labels = [solve_cover(oracle, covered, node_limit=limit) for limit in (1, 3, 10**4)]
    now = [time.perf_counter()]

    def fast_clock() -> float:
        now[0] += 1000.0
        return now[0]

    for name in ("perf_counter", "monotonic", "time"):
        monkeypatch.setattr(time, name, fast_clock)
    assert [solve_cover(oracle, covered, node_limit=limit) for limit in (1, 3, 10**4)] == labels
    assert not labels[0].proved and labels[2].proved


def test_nothing_left_is_the_empty_cover():
    oracle = ViewOracle(np.eye(3, dtype=bool))
    assert solve_cover(oracle, oracle.observable.copy(), 200) == Cover((), 0, 0)


# ---------------------------------------------------------------------------------------------
# Labels in generated shards

SMOKE = Path(__file__).resolve().parents[1] / "configs" / "smoke.yaml"


def _digests(folder: Path) -> dict[str, str]:
    return {path.name: hashlib.sha256(path.read_bytes()).hexdigest() for path in sorted(folder.glob("*.h5"))}


@pytest.fixture(scope="module")
def cover_shards(tmp_path_factory):
    """Three built-in shapes with set-cover labels, by one worker and by two."""
    sources = builtin_sources()[:3]
    one, two = tmp_path_factory.mktemp("one"), tmp_path_factory.mktemp("two")
    for out, workers in ((one, 1), (two, 2)):
        config = load_config(SimConfig, SMOKE, ["oracle.cover=true", f"generate.workers={workers}",
                                                "generate.runs_per_shard=2"])
        report = generate(sources, out, config)
        assert not report.failures and report.samples > 0
    return one, two, config


def test_one_and_two_workers_store_the_same_covers(cover_shards):
    one, two, _ = cover_shards
    assert len(_digests(one)) == 6 and _digests(one) == _digests(two)


def test_labels_cut_short_by_the_node_limit_are_the_same_bytes_for_one_and_two_workers(tmp_path, monkeypatch):
    """With one node per state (and no exact search) most labels are not proved, and still the
    same everywhere (two threads: the setting patched here reaches them)."""
    monkeypatch.setattr(setcover, "SEARCH_NODES", 0)
    sources = builtin_sources()[:2]
    for workers in (1, 2):
        config = load_config(SimConfig, SMOKE, ["oracle.cover=true", "oracle.cover_node_limit=1", "views.count=100",
                                                f"generate.workers={workers}", "episode.runs_per_mesh=2",
                                                "generate.backend=threading"])
        generate(sources, tmp_path / str(workers), config)
    assert len(_digests(tmp_path / "1")) == 2 and _digests(tmp_path / "1") == _digests(tmp_path / "2")
    unproved = 0
    for path in (tmp_path / "1").glob("*.h5"):
        with Shard(path) as shard:
            unproved += int((shard["cover_bound"] < shard["cover_size"]).sum())
    assert unproved > 0


def test_every_stored_cover_covers_what_its_state_left(cover_shards):
    """Checked against the mesh's bit matrix: the state's scans (the run's last views so far)
    and the cover together see every observable point; bound <= size <= greedy."""
    one, _, config = cover_shards
    scenes = {}
    for path in sorted(one.glob("*.h5")):
        with Shard(path) as shard:
            assert COVER <= set(shard.file) and "cover: true" in shard.file.attrs["config"]
            mesh_id = shard["mesh_id"][0].decode()
            if mesh_id not in scenes:
                source = next(s for s in builtin_sources() if s.mesh_id == mesh_id)
                scenes[mesh_id] = Scene.build(source.load(config.mesh), config, scene_rng(0, mesh_id))
            oracle = scenes[mesh_id].oracle
            cover, size, bound, greedy = (shard[name] for name in ("cover", "cover_size", "cover_bound", "cover_greedy"))
            run, step, last = shard["run"], shard["step"], shard["last_view"]
            for i in range(len(shard)):
                scanned = last[(run == run[i]) & (step <= step[i])]
                assert len(scanned) == step[i]
                covered = np.bitwise_or.reduce(oracle.visible[scanned], axis=0)
                assert _covers(oracle, covered, np.flatnonzero(cover[i]))
                assert cover[i].sum() == size[i] and bound[i] <= size[i] <= greedy[i]
                assert bound[i] == size[i]  # the smoke scene solves well within the limit
            assert (np.diff(size)[np.diff(run) == 0] >= -1).all()  # one scan removes at most one view


def test_cover_false_writes_todays_bytes_and_datasets(tmp_path):
    sources = builtin_sources()[:2]
    plain, off = tmp_path / "plain", tmp_path / "off"
    generate(sources, plain, load_config(SimConfig, SMOKE, ["generate.workers=1"]))
    generate(sources, off, load_config(SimConfig, SMOKE, ["generate.workers=1", "oracle.cover=false",
                                                          "oracle.cover_node_limit=200"]))
    assert _digests(plain) == _digests(off) and len(_digests(plain)) == 2
    assert list(yaml.safe_load((plain / "config.yaml").read_text())["oracle"]) == ["min_overlap"]
    for path in plain.glob("*.h5"):
        with Shard(path) as shard:
            assert not COVER & set(shard.file) and list(shard.info.config["oracle"]) == ["min_overlap"]


# ---------------------------------------------------------------------------------------------
# SCVP's layout and export


def test_scvp_layout_has_their_directions_at_our_radius():
    anchor = Path(__file__).resolve().parents[2] / "shared" / "anchors" / "scvp_view_space_32.txt"
    config = load_config(SimConfig, None, ["views.layout=scvp-32", "views.count=32", "views.radius=0.3"])
    positions = view_sphere(config.views).positions
    assert positions.shape == (32, 3) and np.allclose(np.linalg.norm(positions, axis=1), 0.3, atol=1e-12)
    if anchor.exists():  # the shipped table is their file, row for row
        theirs = np.loadtxt(anchor, skiprows=1)
        assert int(anchor.read_text().split()[0]) == 32
        assert np.allclose(positions, theirs / np.linalg.norm(theirs, axis=1, keepdims=True) * 0.3, atol=1e-12)


def _voxel_dataset(path: Path) -> tuple[list[str], list[np.ndarray], list[np.ndarray]]:
    """SCVP's ``VOXELDataset`` reading (sc-net/dataset.py): every folder of exactly two files,
    grid = last column of genfromtxt reshaped (1, 32, 32, 32), label = multi-hot of view_ids
    over 64 outputs. (Their ``[:, [-1]]`` needs a 2-D array: genfromtxt's ndmin=2 gives it for
    one column, as their generator writes and their eval script reads.)"""
    roots, grids, labels = [], [], []
    for root, _, files in sorted(os.walk(path)):
        if len(files) == 2:
            grid = np.genfromtxt(os.path.join(root, "grid.txt"), ndmin=2)[:, [-1]]
            ids = np.genfromtxt(os.path.join(root, "view_ids.txt"), dtype=np.int32, ndmin=1).tolist()
            label = np.zeros(64)
            label[ids] = 1
            roots.append(root)
            grids.append(np.reshape(grid, (1, 32, 32, 32)))
            labels.append(label)
    return roots, grids, labels


def test_scvp_export_reads_back_as_their_loader_reads_it(tmp_path):
    shards = tmp_path / "shards"
    config = load_config(SimConfig, SMOKE, ["oracle.cover=true", "views.layout=scvp-32", "views.count=32",
                                            "generate.workers=1", "episode.runs_per_mesh=2"])
    generate(builtin_sources()[:1], shards, config)
    out = tmp_path / "scvp"
    assert main(["export", str(shards), "--format", "scvp", "--out", str(out)]) == 0
    (path,) = sorted(shards.glob("*.h5"))
    with Shard(path) as shard:
        grids, covers, positions = shard.grids(), shard["cover"], shard["view_positions"]
    roots, read_grids, labels = _voxel_dataset(out)
    assert len(roots) == len(grids) > 0
    for root, grid, label in zip(roots, read_grids, labels):
        index = int(Path(root).name)
        assert Path(root).parent.name == path.stem
        assert np.array_equal(grid[0].astype(np.float32), grids[index])  # [x, y, z], exact
        assert np.array_equal(label[:32].astype(bool), covers[index]) and not label[32:].any()
    space = (out / "view_space.txt").read_text().split("\n")
    assert space[0] == "32" and np.array_equal(np.loadtxt(space[1:33]), positions)
    assert np.genfromtxt(Path(roots[0]) / "grid.txt").reshape(1, 1, 32, 32, 32).shape  # their eval's reading


@pytest.mark.parametrize("overrides, message", [
    ([], "no set-cover labels, 60 candidate views (SCVP's format has their 32); generate with --set "
         "oracle.cover=true --set views.layout=scvp-32 --set views.count=32 to export --format scvp"),
    (["oracle.cover=true"], ": 60 candidate views (SCVP's format has their 32); generate with --set "
                            "views.layout=scvp-32 --set views.count=32 to export"),
])
def test_scvp_export_refuses_shards_it_cannot_hold_in_one_line(tmp_path, capsys, overrides, message):
    """Every setting the shards lack is in the first message (each one found later cost a regeneration)."""
    config = load_config(SimConfig, SMOKE, [*overrides, "generate.workers=1", "episode.runs_per_mesh=1"])
    generate(builtin_sources()[:1], tmp_path / "shards", config)
    assert main(["export", str(tmp_path / "shards"), "--format", "scvp", "--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err
    assert message in error and len(error.strip().splitlines()) == 1 and not (tmp_path / "out").exists()


def test_bad_cover_settings_are_one_line_errors(capsys):
    for setting, message in (("oracle.cover_node_limit=0", "oracle.cover_node_limit=0: must be >= 1 branch-and-bound node"),
                             ("views.layout=scvp-33", "views.layout='scvp-33': must be one of"),
                             ("views.layout=scvp-32", "views.layout=scvp-32 has 32 views: set views.count=32")):
        assert main(["generate", "--out", "/nonexistent/never", "--set", setting]) == 2
        error = capsys.readouterr().err
        assert message in error and len(error.strip().splitlines()) == 1


# ---------------------------------------------------------------------------------------------
# The evaluation's scans to X %, floors and set-cover planner


def _eval_row(planner: str, start: int, scan: int, observable: float) -> dict:
    return {"mesh": "cube", "planner": planner, "start": start, "start_view": 0, "scan": scan, "coverage": observable,
            "observable_coverage": observable, "seconds": 0.0, "x": 0.0, "y": 0.0, "z": 0.4, "overlap": None,
            "valid_views": None}


def test_scans_to_each_share_on_hand_made_runs():
    """Start 0 covers 50, 90, 96, 99.5 % after scans 1-4: 90 % at scan 2, 95 % at 3, 99 % at 4;
    start 1 reaches 92 % and no more: 95 and 99 % are not reached."""
    rows = [_eval_row("p", 0, scan, value) for scan, value in enumerate((0.5, 0.9, 0.96, 0.995), start=1)]
    rows += [_eval_row("p", 1, scan, value) for scan, value in enumerate((0.6, 0.92, 0.92, 0.92), start=1)]
    assert scans_to(rows) == {("cube", "p"): [[2, 3, 4], [2, None, None]]}
    floors = [{"mesh": "cube", "start": 0, "start_view": 0, "cover_size": 3, "cover_bound": 3, "cover_greedy": 4},
              {"mesh": "cube", "start": 1, "start_view": 5, "cover_size": 4, "cover_bound": 3, "cover_greedy": 5}]
    (line,) = [line for line in scans_table(rows, floors, ["p"]) if line.startswith("| cube |")]
    assert line == "| cube | 2.0 / n.r. / n.r. | >= 4.0 (best 4.5) | 5.5 |"


def test_setcover_planner_reaches_everything_in_exactly_the_floors_scans(tmp_path):
    """Noise-free, the planned views cover all the observable surface: the set-cover planner
    reaches 100 % at scan 1 + the floor (no planner can earlier), the greedy oracle no earlier."""
    config = load_config(SimConfig, SMOKE, ["views.count=24"])
    source = builtin_sources()[0]
    planners, _ = build_planners(["oracle", "setcover"], config, view_sphere(config.views), {})
    report = evaluate([source], planners, config, scans=26, random_starts=1)
    (floor_0, floor_1) = report.floors
    reached = scans_to(report.rows, (1.0,))
    for start, floor in enumerate((floor_0, floor_1)):
        assert floor["cover_bound"] == floor["cover_size"] <= floor["cover_greedy"]
        assert reached[(source.stem, "setcover")][start] == [1 + floor["cover_size"]]
        oracle = reached[(source.stem, "oracle")][start][0]
        assert oracle is None or oracle >= 1 + floor["cover_size"]
    write_outputs(report, tmp_path, ["oracle", "setcover"], [], {})
    summary = (tmp_path / "summary.md").read_text()
    assert "| floor (100 %) | greedy cover (100 %) |" in summary and "setcover" in summary
    assert (tmp_path / "floors.csv").read_text().splitlines()[0] == ",".join(FLOOR_COLUMNS)


def test_evaluating_without_floors_leaves_them_out_and_changes_no_row():
    config = load_config(SimConfig, SMOKE, [])
    source = builtin_sources()[0]
    planners, _ = build_planners(["oracle", "random"], config, view_sphere(config.views), {})
    with_floors = evaluate([source], planners, config, scans=4, random_starts=1)
    without = evaluate([source], planners, config, scans=4, random_starts=1, floors=False)
    assert len(with_floors.floors) == 2 and without.floors == []
    drop = lambda rows: [{k: v for k, v in row.items() if k != "seconds"} for row in rows]  # noqa: E731
    assert drop(without.rows) == drop(with_floors.rows)


def test_inspect_and_the_card_show_the_labels_by_step(cover_shards, tmp_path, capsys):
    from nbvdata.datasets.publish import publish

    one, _, _ = cover_shards
    assert main(["inspect", str(one)]) == 0
    printed = capsys.readouterr().out
    assert "set-cover labels by step" in printed and "\n   1 " in printed and "100.0%" in printed
    card = publish(one, "covered", "1.0.0", tmp_path / "manifests", about=about()).path.with_suffix(".md").read_text()
    assert "- Set-cover labels (`oracle.cover`" in card and "set-cover labels by step" in card
    for dataset in COVER:
        assert f"| `{dataset}` | (N" in card


@pytest.mark.parametrize("seed", range(30))
def test_canonical_search_finds_the_smallest_optimal_set_from_any_optimal_one(seed):
    """Handed the lexicographically largest optimal cover (what another solver path might return),
    the search returns the smallest, as brute force finds it."""
    rng = np.random.default_rng(200 + seed)
    oracle = _instance(rng, views=int(rng.integers(5, 13)), points=int(rng.integers(10, 60)), density=0.25)
    covered = np.zeros_like(oracle.observable)
    optimum, smallest = _brute_force(oracle, covered)
    optimal = [views for views in itertools.combinations(range(len(oracle)), optimum)
               if _covers(oracle, covered, views)]
    rows = _minimal_rows(oracle, oracle.observable & ~covered)
    found = _lexicographic_cover(rows, _candidates(rows), optimum, list(optimal[-1]), setcover.NodeBudget(10**6))
    assert tuple(found) == smallest == optimal[0]


def test_the_size_may_drop_by_one_after_a_view_outside_the_cover():
    """Views A = {p0, p1}, B = {p2, p3}, C = {p0, p2}, D = {p1, p3}: the cover of all is {A, B};
    after scanning C (not in it) D alone covers the rest, so the bound opt - 1 must be reachable."""
    oracle = ViewOracle(np.array([[1, 1, 0, 0], [0, 0, 1, 1], [1, 0, 1, 0], [0, 1, 0, 1]], dtype=bool))
    first = solve_cover(oracle, np.zeros_like(oracle.observable), 200)
    assert first.views == (0, 1) and first.proved
    label = next_cover(oracle, oracle.visible[2].copy(), first, 2, 200)
    assert label.views == (3,) and label.proved


def test_setcover_planner_scans_the_plan_in_the_shortest_tour_order():
    """Plan {0, 1, 2} (views at 90, 180 and 30 degrees round the equator) from a sensor at 0 degrees:
    the shortest tour is 30, 90, 180 degrees - views 2, 0, 1 - though view 0 sees the most."""
    from nbvdata.core.views import ViewSet, look_at_rotations
    from nbvtrain.planners import Observation

    angles = np.radians([90.0, 180.0, 30.0, 0.0])
    positions = 0.4 * np.stack([np.cos(angles), np.sin(angles), np.zeros(4)], axis=1)
    views = ViewSet(positions, look_at_rotations(positions))
    visible = np.zeros((4, 10), dtype=bool)
    visible[0, :6] = visible[1, 6:8] = visible[2, 8:] = True
    oracle = ViewOracle(visible)
    planner = SetCoverPlanner(views=views)
    planner.start(0)
    scene = SimpleNamespace(oracle=oracle, bounding_radius=0.1, plan_cover=lambda covered: solve_cover(oracle, covered, 200))
    truth = SimpleNamespace(scene=scene, covered=np.zeros_like(oracle.observable))
    poses, order = [views[3]], []
    for _ in range(3):
        pose = planner.next_pose(Observation(None, tuple(poses)), truth)
        view = int(np.flatnonzero((positions == pose.position).all(axis=1))[0])
        order.append(view)
        poses.append(pose)
        truth.covered = truth.covered | oracle.visible[view]
    assert order == [2, 0, 1]


@pytest.mark.parametrize("seed", [2, 249, 305])
def test_a_view_outside_the_cover_can_still_lower_the_optimum(seed):
    """Instances (found by search) where the view scanned is in no previous cover, yet the optimum
    drops by one and neither the previous cover nor the greedy one shows it: the solver must."""
    rng = np.random.default_rng(seed)
    oracle = _instance(rng, views=int(rng.integers(6, 12)), points=40, density=0.2)
    previous = solve_cover(oracle, np.zeros_like(oracle.observable), 30)
    view = int(rng.integers(len(oracle)))
    covered = oracle.visible[view].copy()
    label = next_cover(oracle, covered, previous, view, 30)
    assert view not in previous.views and label.greedy == previous.size
    assert label.size == previous.size - 1 == _brute_force(oracle, covered)[0] and label.proved


def test_cover_shards_are_byte_identical_with_an_old_cpus_arithmetic(tmp_path):
    """As tests/test_determinism.py does for the default data: numpy's, OpenBLAS's and numba's
    arithmetic of the oldest x86-64 CPU give the same labels (HiGHS's own path may differ; the
    canonical set does not)."""
    from test_determinism import OLD_CPU

    def generate_in(out: Path, env: dict | None) -> None:
        command = [sys.executable, "-m", "nbvdata", "generate", "--out", str(out), "--config", str(SMOKE),
                   "--workers", "1", "--runs-per-mesh", "2", "--set", "oracle.cover=true", "--no-progress"]
        result = subprocess.run(command, capture_output=True, text=True, env=env)
        assert result.returncode == 0, result.stderr

    generate_in(tmp_path / "here", None)
    generate_in(tmp_path / "old", os.environ | OLD_CPU | {"NUMBA_CACHE_DIR": str(tmp_path / "jit")})
    assert len(_digests(tmp_path / "here")) == 6 and _digests(tmp_path / "here") == _digests(tmp_path / "old")


@pytest.mark.parametrize("seed", range(40))
def test_another_solver_path_stores_the_same_set(seed, monkeypatch):
    """Whatever optimal set the solver returns first (here: the lexicographically largest, as
    another machine's HiGHS might), the stored label is the same."""
    rng = np.random.default_rng(seed)
    oracle = _instance(rng, views=int(rng.integers(4, 13)), points=int(rng.integers(10, 60)),
                       density=float(rng.uniform(0.08, 0.4)))
    covered = np.zeros_like(oracle.observable)
    expected = solve_cover(oracle, covered, 30)
    optimum = _brute_force(oracle, covered)[0]
    largest = [views for views in itertools.combinations(range(len(oracle)), optimum)
               if _covers(oracle, covered, views)][-1]
    solve, calls = setcover._milp, []

    def other_path(rows, columns, lower, upper, seconds):
        calls.append(1)
        if len(calls) == 1 and lower <= optimum <= upper:  # the first solve: another optimal set
            return list(largest), optimum, True
        return solve(rows, columns, lower, upper, seconds)

    monkeypatch.setattr(setcover, "_milp", other_path)
    assert solve_cover(oracle, covered, 30) == expected
