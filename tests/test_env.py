"""The Gymnasium environment nbvdata/Reconstruct-v0: Gymnasium's checker, rewards that add up to the
coverage gained, the oracle's scores equal to the generator's shards, seeding, a vector env equal to
single envs, the view state, action masks, bad input, and RL policies in nbvtrain evaluate."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium", reason="gymnasium (the [rl] extra) is not installed")

from gymnasium.utils.env_checker import check_env  # noqa: E402

import nbvdata.env  # noqa: E402  (registers nbvdata/Reconstruct-v0)
from nbvdata.core.config import ConfigError, SimConfig, load_config  # noqa: E402
from nbvdata.datasets.generate import generate  # noqa: E402
from nbvdata.env import ENV_ID, ReconstructEnv  # noqa: E402
from nbvdata.schema.shards import Shard  # noqa: E402
from nbvdata.simulation.episode import Reconstruction, start_view  # noqa: E402
from nbvdata.simulation.mesh import MeshError  # noqa: E402
from nbvdata.simulation.shapes import BUILTIN_SHAPES  # noqa: E402
from nbvdata.simulation.sources import builtin_sources  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "configs" / "smoke.yaml"
TWO = ["builtin:mug", "builtin:ring"]


@pytest.fixture(scope="module")
def config() -> SimConfig:
    return load_config(SimConfig, SMOKE)


@pytest.fixture(scope="module")
def env(config) -> ReconstructEnv:
    """Candidate-view actions, the oracle's scores in info; scenes kept across the tests."""
    return ReconstructEnv(TWO, config, info_scores=True)


@pytest.fixture(scope="module")
def pose_env(config) -> ReconstructEnv:
    return ReconstructEnv(TWO, config, action="pose")


def _episode(env: ReconstructEnv, actions, **reset) -> tuple[list[tuple], list]:
    """The steps (observation, reward, terminated, truncated, info) from reset (reward None) to
    the episode's end, or until ``actions(observation, info)`` gives None, and the actions."""
    observation, info = env.reset(**reset)
    steps, taken = [(observation, None, False, False, info)], []
    while not (steps[-1][2] or steps[-1][3]):
        action = actions(observation, info)
        if action is None:
            break
        observation, reward, terminated, truncated, info = env.step(action)
        steps.append((observation, reward, terminated, truncated, info))
        taken.append(action)
    return steps, taken


def _random_views(seed: int):
    rng = np.random.default_rng(seed)
    return lambda observation, info: int(rng.integers(len(observation["taken"])))


def _random_directions(seed: int):
    rng = np.random.default_rng(seed)
    return lambda observation, info: rng.normal(size=3) + np.array([0.0, 0.0, 1.0])


def _same(a, b) -> bool:
    """Two observations, infos or steps hold the same values (NaN equal to NaN)."""
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (tuple, list)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return np.array_equal(a, b, equal_nan=isinstance(a, float) or (isinstance(a, np.ndarray) and a.dtype.kind == "f"))


def test_gymnasiums_checker_passes(env, pose_env):
    check_env(env, skip_render_check=True)
    check_env(pose_env, skip_render_check=True)


def test_gymnasium_make_builds_it_by_its_id(config):
    made = gymnasium.make(ENV_ID, meshes=TWO, config=config, info_scores=True)
    assert isinstance(made.unwrapped, ReconstructEnv) and made.unwrapped.info_scores
    observation, info = made.reset(seed=0)
    assert made.observation_space.contains(observation) and info["mesh"] in TWO
    made.close()
    # Gymnasium 1.x reads no plugin entry points: "module:id" imports the module that registers it.
    code = ("import gymnasium, sys; env = gymnasium.make('nbvdata.env:nbvdata/Reconstruct-v0', "
            f"meshes=['builtin:ring'], config={str(SMOKE)!r}); print(env.reset(seed=1)[1]['mesh'])")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 0 and done.stdout.strip() == "builtin:ring", done.stderr


@pytest.mark.parametrize("kind", ["view", "pose", "noisy pose"])
def test_rewards_add_up_to_the_observable_coverage_gained(env, pose_env, config, kind):
    """The rewards add up to the final observable coverage minus the start scan's; noise-free,
    each step's observable coverage is that of the same scans in the generator's Reconstruction,
    and a view's reward is the oracle's gain of it."""
    if kind == "noisy pose":
        env = ReconstructEnv(TWO, config, ["sensor.noise_std=0.002"], action="pose")
    elif kind == "pose":
        env = pose_env
    actions = _random_views(3) if kind == "view" else _random_directions(3)
    for seed in range(4):
        steps, taken = _episode(env, actions, seed=seed)
        first, last = steps[0][-1], steps[-1][-1]
        rewards = [step[1] for step in steps[1:]]
        assert len(rewards) >= 1 and last["observable_coverage"] > first["observable_coverage"]
        assert sum(rewards) == pytest.approx(last["observable_coverage"] - first["observable_coverage"], abs=1e-12)
        if kind == "noisy pose":
            continue
        scene = env.state.scene
        replay = Reconstruction(scene, None, np.random.default_rng(0))  # live scans, as nbvtrain evaluate
        replay.scan(first["view"])
        for action, (_, reward, _, _, info), (_, _, _, _, before) in zip(taken, steps[1:], steps):
            if kind == "view":
                replay.scan(action)
                assert np.float32(reward) == before["gains"][action]
            else:
                replay.scan_pose(nbvdata.env.direction_pose(action, scene.views)[1])
            assert info["observable_coverage"] == scene.oracle.observable_coverage(replay.covered)
            assert reward == pytest.approx(info["observable_coverage"] - before["observable_coverage"], abs=1e-15)


@pytest.mark.parametrize("overrides", [[], ["episode.min_gain=0.05", "episode.max_scans=50"]],
                         ids=["max_scans", "min_gain"])
def test_info_scores_equal_the_generators_shard_rows(env, config, tmp_path, overrides):
    """From a generated run's start view, following its moves: every state's grid, gains,
    overlaps, NBV and observable coverage are the shard's row, and the episode ends where the run
    does (terminated where the generator found no view worth a scan, truncated at max_scans)."""
    if overrides:  # runs that stop for want of a view adding min_gain
        env = ReconstructEnv(TWO, config, overrides, info_scores=True)
        config = env.config
    mug = builtin_sources(config.mesh)[0]
    assert mug.name == "builtin:mug"
    generate([mug], tmp_path, config, show_progress=False)
    (path,) = tmp_path.glob("*.h5")
    with Shard(path) as shard:
        rows = {name: shard[name] for name in ("run", "step", "gains", "overlaps", "nbv_index", "coverage",
                                              "last_view")}
        grids = shard.grids()
    stopped = 0
    for run in range(config.episode.runs_per_mesh):
        mine = np.flatnonzero(rows["run"] == run)
        start = start_view(config.episode.seed, mug.mesh_id, config.views.count, run)
        assert rows["last_view"][mine[0]] == start
        moves = iter(rows["nbv_index"][mine])
        steps, _ = _episode(env, lambda observation, info: next(moves, None),
                            options={"mesh": "builtin:mug", "start_view": start})
        assert len(steps) >= len(mine)
        for row, (observation, _, _, _, info) in zip(mine, steps):
            assert np.array_equal(observation["grid"], grids[row])
            assert np.array_equal(info["gains"], rows["gains"][row])
            assert np.array_equal(info["overlaps"], rows["overlaps"][row])
            assert info["nbv"] == rows["nbv_index"][row]
            assert np.float32(info["observable_coverage"]) == rows["coverage"][row, 0]
        if len(mine) == config.episode.max_scans:  # the run recorded its last state
            assert len(steps) == len(mine) and steps[-1][3] and not steps[-1][2]
        else:  # the run stopped: the state after its last move had no view worth a scan
            assert len(steps) == len(mine) + 1 and steps[-1][2] and steps[-1][-1]["nbv"] == -1
            stopped += 1
    assert stopped == (config.episode.runs_per_mesh if overrides else 0)


def test_the_same_seed_gives_the_same_trajectory(config):
    """Two fresh environments, the same seed and actions: the same episodes, also after resets
    without a seed (the stream goes on) and with range noise; other seeds start elsewhere."""
    overrides = ["sensor.noise_std=0.002"]
    runs = []
    for _ in range(2):
        fresh = ReconstructEnv(TWO, config, overrides, action="pose")
        actions = _random_directions(5)
        runs.append([_episode(fresh, actions, seed=11)[0]] + [_episode(fresh, actions)[0] for _ in range(2)])
    assert _same(runs[0], runs[1])
    fresh = ReconstructEnv(TWO, config)
    starts = {(info["mesh"], info["view"]) for info in (fresh.reset(seed=seed)[1] for seed in range(6))}
    assert len(starts) >= 4
    assert _same(fresh.reset(seed=3), fresh.reset(seed=3))


def test_a_vector_env_of_two_equals_two_single_envs(config):
    """AsyncVectorEnv (its default next-step autoreset) against two single environments, across
    episode ends. forkserver: numba's OpenMP layer aborts a child forked after the parent has
    scanned (docs/env.md)."""
    make = [lambda: ReconstructEnv(TWO, config, threads=1)] * 2
    vector = gymnasium.vector.AsyncVectorEnv(make, context="forkserver")
    singles = [ReconstructEnv(TWO, config), ReconstructEnv(TWO, config)]
    try:
        observations, infos = vector.reset(seed=[21, 22])
        expected = [single.reset(seed=seed) for single, seed in zip(singles, (21, 22))]
        rng, done, ends = np.random.default_rng(0), [False, False], 0
        for step in range(10):
            for k, (observation, info) in enumerate(expected):
                assert np.array_equal(observations["grid"][k], observation["grid"])
                assert np.array_equal(observations["taken"][k], observation["taken"])
                assert infos["observable_coverage"][k] == info["observable_coverage"]
                assert infos["mesh"][k] == info["mesh"]
            actions = rng.integers(config.views.count, size=2)
            observations, rewards, terminated, truncated, infos = vector.step(actions)
            expected = []
            for k, single in enumerate(singles):
                if done[k]:  # next-step autoreset: this step only resets
                    expected.append(single.reset())
                    reward, ended = 0.0, (False, False)
                else:
                    observation, reward, *ended, info = single.step(actions[k])
                    expected.append((observation, info))
                assert rewards[k] == reward and (terminated[k], truncated[k]) == tuple(ended)
                done[k] = any(ended)
                ends += done[k]
        assert ends >= 2
    finally:
        vector.close()


def test_taken_marks_exactly_the_views_scanned(config):
    longer = ["episode.max_scans=8", "episode.min_gain=0"]
    env, pose_env = ReconstructEnv(TWO, config, longer), ReconstructEnv(TWO, config, longer, action="pose")
    views = env.views
    _, info = env.reset(seed=4)
    scanned = {info["view"]}
    for action in (7, 7, 30, 59):
        observation, *_, info = env.step(action)
        scanned.add(action)
        assert set(np.flatnonzero(observation["taken"])) == scanned and info["view"] == action
    observation, info = pose_env.reset(seed=4, options={"start_view": 5})
    scanned = {5}
    rng = np.random.default_rng(2)
    for direction in [views.unit_positions[12], views.positions[40] * 3, *rng.normal(size=(2, 3))]:
        observation, *_, info = pose_env.step(direction)
        nearest = int(np.argmax(views.unit_positions @ (direction / np.linalg.norm(direction))))
        scanned.add(nearest)
        assert info["view"] == nearest and set(np.flatnonzero(observation["taken"])) == scanned
    assert {12, 40} <= scanned


def _random_masked(seed: int):
    """A uniformly random choice among the views the mask allows."""
    rng = np.random.default_rng(seed)
    return lambda observation, info: int(rng.choice(np.flatnonzero(info["action_mask"])))


@pytest.mark.parametrize("mask_invalid", [False, True])
def test_a_random_masked_policy_never_repeats_a_view(config, mask_invalid):
    """Smoke scene of 60 views, 40 scans a run: a masked random agent takes every view once at
    most, the mask is exactly the unscanned views (with mask_invalid: those keeping the overlap
    rule, where any does), and action_masks() is info["action_mask"]."""
    long = ["episode.max_scans=40", "episode.min_gain=0"]
    env = ReconstructEnv(TWO, config, long, info_scores=True, mask_invalid=mask_invalid)
    rule, repeats, episodes, narrowed = config.oracle.min_overlap, 0, 0, 0
    for seed in range(6):
        steps, taken = _episode(env, _random_masked(seed), seed=seed)
        episodes += 1
        views = [steps[0][4]["view"], *taken]
        repeats += len(views) - len(set(views))
        for observation, _, terminated, truncated, info in steps:
            unscanned = observation["taken"] == 0
            if terminated or truncated:
                continue
            expected = unscanned
            if mask_invalid and (unscanned & (info["overlaps"] >= rule)).any():
                expected = unscanned & (info["overlaps"] >= rule)
                narrowed += int(expected.sum() < unscanned.sum())
            assert np.array_equal(info["action_mask"], expected)
            assert info["action_mask"].any()
        assert np.array_equal(env.action_masks(), steps[-1][4]["action_mask"])
        assert len(views) > 10  # long episodes: a repeat had every chance
    assert repeats == 0 and episodes == 6
    assert narrowed > 0 if mask_invalid else narrowed == 0  # the overlap rule did leave views out


def test_the_checker_passes_with_masks_and_they_cross_wrappers(config):
    env = ReconstructEnv(TWO, config, mask_invalid=True)
    check_env(env, skip_render_check=True)
    made = gymnasium.make(ENV_ID, meshes=TWO, config=config, mask_invalid=True)
    _, info = made.reset(seed=3)
    assert np.array_equal(made.get_wrapper_attr("action_masks")(), info["action_mask"])
    assert info["action_mask"].dtype == bool and info["action_mask"].shape == (made.action_space.n,)
    with pytest.raises(TypeError, match="mask_invalid=1: must be True or False"):
        ReconstructEnv(TWO, config, mask_invalid=1)


def test_the_overlap_penalty_applies_to_moves_that_break_the_rule(config):
    penalised = ReconstructEnv(TWO, config, info_scores=True, overlap_penalty=0.25)
    _, info = penalised.reset(seed=2)
    rule = config.oracle.min_overlap
    for pick in (np.argmin, lambda overlaps: int(np.flatnonzero(overlaps >= rule)[0])):
        action = int(pick(info["overlaps"]))
        gain, overlap = info["gains"][action], info["overlaps"][action]
        _, reward, *_, info = penalised.step(action)
        assert info["overlap"] == pytest.approx(overlap, abs=1e-6)
        assert np.float32(reward + (0.25 if overlap < rule else 0.0)) == gain
    assert reward >= 0  # the second move kept the rule


def test_a_reset_on_a_mesh_seen_before_builds_no_scene(config, monkeypatch):
    import nbvdata.datasets.generate as job

    built = []
    build = job.Scene.build
    monkeypatch.setattr(job.Scene, "build", lambda obj, *rest: built.append(obj.source) or build(obj, *rest))
    kept = ReconstructEnv(TWO, config)
    for seed in range(6):
        kept.reset(seed=seed)
    assert sorted(built) == TWO
    built.clear()
    one = ReconstructEnv(TWO, config, scene_cache=1)
    for mesh in ("mug", "mug", "ring", "ring", "mug"):
        one.reset(options={"mesh": mesh})
    assert built == ["builtin:mug", "builtin:ring", "builtin:mug"]
    built.clear()
    ReconstructEnv(TWO, config, scene_cache=0).reset(seed=0)  # no cache: one build per reset, not two
    assert len(built) == 1


def test_bad_actions_raise_naming_the_value_and_leave_the_episode_as_it_was(env, pose_env):
    observation, _ = env.reset(seed=0)
    for action, error, words in [(60, ValueError, "action 60: out of range; a candidate view index in 0..59"),
                                 (-1, ValueError, "action -1: out of range"), (2.0, TypeError, "action 2.0: must be"),
                                 ("3", TypeError, "action '3'"), (True, TypeError, "action True"),
                                 (np.array([1, 2]), TypeError, "action array([1, 2])")]:
        with pytest.raises(error, match=words.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
            env.step(action)
    assert env.state.scans == 1 and np.array_equal(env.state.grid.probabilities(), observation["grid"])
    after = env.step(np.int64(3))
    fresh = ReconstructEnv(TWO, env.config, info_scores=True)
    fresh.reset(seed=0)
    assert _same(after, fresh.step(3))
    pose_env.reset(seed=0)
    for action, words in [([np.nan, 0, 1], "action \\[nan, 0, 1\\]: must be a finite, non-zero direction"),
                          ([0, 0, 0], "non-zero"), ([np.inf, 0, 0], "finite"), ([1, 0], "of shape \\(3,\\)"),
                          ("up", "of shape")]:
        with pytest.raises(ValueError, match=words):
            pose_env.step(action)
    assert pose_env.state.scans == 1


def test_steps_outside_an_episode_need_a_reset(config):
    fresh = ReconstructEnv(TWO, config)
    with pytest.raises(gymnasium.error.ResetNeeded):
        fresh.step(0)
    steps, _ = _episode(fresh, _random_views(0), seed=0)
    with pytest.raises(gymnasium.error.ResetNeeded):
        fresh.step(0)


@pytest.mark.parametrize("options, error, words", [
    ([("mesh", 0)], TypeError, r"reset\(options=\[\('mesh', 0\)\]\): must be a dict"),
    ({"mesh": 2.5}, TypeError, r"options\['mesh'\]=2.5: must be a mesh's index or name"),
    ({"mesh": 2}, ValueError, r"options\['mesh'\]=2: out of range; this environment has 2 meshes"),
    ({"mesh": "teapot"}, ValueError, r"options\['mesh'\]='teapot': is none of the meshes \(builtin:mug"),
    ({"start_view": 60}, ValueError, r"options\['start_view'\] 60: out of range"),
    ({"start_view": "3"}, TypeError, r"options\['start_view'\] '3': must be an integer"),
    ({"start": 3}, ValueError, "unknown key\\(s\\) 'start'; known: mesh, start_view"),
])
def test_bad_reset_options_raise_naming_the_value(env, options, error, words):
    env.reset(seed=0)
    before, stream = env.state, env.np_random.bit_generator.state
    with pytest.raises(error, match=words):
        env.reset(seed=1, options=options)
    assert env.state is before and env.np_random.bit_generator.state == stream
    env.step(1)  # the episode goes on


def test_bad_settings_and_meshes_raise_naming_the_value(config, tmp_path):
    for kwargs, error, words in [
        ({"action": "teleport"}, ValueError, "action='teleport': must be 'view'"),
        ({"overlap_penalty": -1}, ValueError, "overlap_penalty=-1: must be a finite number >= 0"),
        ({"overlap_penalty": float("nan")}, ValueError, "overlap_penalty=nan"),
        ({"info_scores": "yes"}, TypeError, "info_scores='yes'"),
        ({"scene_cache": -2}, ValueError, "scene_cache=-2"),
        ({"threads": 1.5}, ValueError, "threads=1.5"),
        ({"config": 42}, TypeError, "config=42: must be a SimConfig"),
        ({"overrides": ["episode.max_scan=4"]}, ConfigError, "did you mean 'episode.max_scans'"),
        ({"overrides": ["episode.max_scans=1"]}, ConfigError, "episode.max_scans=1: an episode needs >= 2 scans"),
        ({"overrides": "views.count=9"}, TypeError, "overrides='views.count=9'"),
        ({"meshes": 7}, TypeError, "meshes=7: must be a folder"),
        ({"meshes": []}, TypeError, "meshes=\\[\\]"),
        ({"meshes": ["builtin:teapot"]}, ValueError, "'builtin:teapot' is no built-in shape"),
        ({"meshes": tmp_path / "absent"}, MeshError, "absent: no such file or folder"),
    ]:
        with pytest.raises(error, match=words):
            ReconstructEnv(**({"meshes": TWO, "config": config} | kwargs))
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(MeshError, match="no mesh files"):
        ReconstructEnv(empty, config)
    (empty / "notes.ply").write_text("these are notes, not a mesh\n")
    with pytest.warns(UserWarning, match="skipping mesh .*notes.ply: .*not a valid PLY file"), \
            pytest.raises(MeshError, match="no usable mesh"):
        ReconstructEnv(empty, config)


def test_meshes_that_fail_to_load_are_skipped_until_none_is_left(config, tmp_path):
    folder = tmp_path / "meshes"
    folder.mkdir()
    (folder / "broken.obj").write_text("v 0 0 0\nv 1 0 0\n")  # an OBJ without faces
    broken = ReconstructEnv(folder, config)
    with pytest.raises(ValueError, match="no usable mesh among the 1 given: .*broken.obj"), pytest.warns(UserWarning):
        broken.reset(seed=0)
    with pytest.raises(ValueError, match="no usable mesh among the 1 given"):  # known now: no second try
        broken.reset(seed=1)
    BUILTIN_SHAPES["ring"]().export(folder / "ring.obj")
    mixed = ReconstructEnv(folder, config)
    with pytest.warns(UserWarning, match="skipping mesh broken.obj"):
        meshes = {mixed.reset(seed=seed)[1]["mesh"] for seed in range(4)}
    assert meshes == {"ring.obj"}
    with pytest.raises(ValueError, match="options\\['mesh'\\]='broken': broken.obj cannot be used"):
        mixed.reset(options={"mesh": "broken"})


@pytest.fixture(scope="module")
def mesh_folder(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("meshes")
    for name in ("mug", "ring"):
        BUILTIN_SHAPES[name]().export(folder / f"{name}.obj")
    return folder


def test_evaluate_runs_a_policy_on_the_envs_observation_in_the_same_table(config, mesh_folder, tmp_path, capsys):
    """``--planners env_policies:first_untaken,random``: one table; the policy saw exactly the
    environment's observations of the same mesh, start and moves, and the coverage is the env's."""
    import env_policies

    from nbvtrain.cli import main

    env_policies.SEEN.clear()
    out = tmp_path / "eval"
    policy = "env_policies:first_untaken"
    assert main(["evaluate", "--meshes", str(mesh_folder), "--planners", f"{policy},random,oracle", "--scans", "4",
                 "--config", str(SMOKE), "--out", str(out), "--no-progress"]) == 0
    with open(out / "coverage.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert {row["planner"] for row in rows} == {policy, "random", "oracle"}
    assert f"| object | {policy} | random | oracle |" in (out / "summary.md").read_text()
    env = ReconstructEnv(mesh_folder, config)
    seen = iter(env_policies.SEEN)
    for mesh in ("mug", "ring"):
        run = [row for row in rows if row["mesh"] == mesh and row["planner"] == policy]
        steps, _ = _episode(env, lambda observation, info: first_untaken_again(observation, next(seen)),
                            options={"mesh": mesh, "start_view": int(run[0]["start_view"])})
        assert len(steps) == 4
        for row, (_, _, _, _, info) in zip(run, steps):
            assert float(row["coverage"]) == pytest.approx(info["coverage"], abs=1e-6)
            assert float(row["observable_coverage"]) == pytest.approx(info["observable_coverage"], abs=1e-6)
    assert next(seen, None) is None


def test_a_policy_that_raises_on_every_mesh_leaves_a_readable_summary_and_its_traceback(mesh_folder, tmp_path):
    """Every mesh failed: exit 1, summary.md says there is nothing to compare (not "0 objects ...
    after scan 0"), failures.tsv names each mesh, tracebacks.txt has where the policy raised."""
    from nbvtrain.cli import main

    out = tmp_path / "eval"
    assert main(["evaluate", "--meshes", str(mesh_folder), "--planners", "env_policies:crashes", "--scans", "2",
                 "--config", str(SMOKE), "--out", str(out), "--no-progress"]) == 1
    summary = (out / "summary.md").read_text()
    assert summary.startswith("# Closed-loop evaluation: no object evaluated") and "after scan 0" not in summary
    assert "raised ZeroDivisionError" in summary and len((out / "failures.tsv").read_text().splitlines()) == 3
    traces = (out / "tracebacks.txt").read_text()
    assert traces.count("== ") == 2 and "in _deeper" in traces and "a bug in the user's policy" in traces
    assert not (out / "plots").exists()


def first_untaken_again(observation: dict, seen: dict) -> int:
    """The env's observation must be the one evaluate gave the policy; then the policy's move."""
    assert observation.keys() == seen.keys() == {"grid", "taken"}
    assert np.array_equal(observation["grid"], seen["grid"]) and observation["grid"].dtype == seen["grid"].dtype
    assert np.array_equal(observation["taken"], seen["taken"]) and seen["taken"].dtype == np.int8
    return int(np.argmin(observation["taken"]))


def test_evaluate_takes_a_direction_policy_from_a_file_and_rejects_bad_ones(mesh_folder, tmp_path, capsys):
    from nbvtrain.cli import main

    out = tmp_path / "eval"
    policies = Path(__file__).with_name("env_policies.py")
    spec = f"{policies}:toward_unknown"
    assert main(["evaluate", "--meshes", str(mesh_folder / "ring.obj"), "--planners", spec, "--scans", "3",
                 "--config", str(SMOKE), "--out", str(out), "--no-progress"]) == 0
    with open(out / "coverage.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 3 and {row["planner"] for row in rows} == {spec}
    radius = np.linalg.norm([[float(row[axis]) for axis in "xyz"] for row in rows], axis=1)
    assert np.allclose(radius, 0.4)  # directions placed on the view sphere
    capsys.readouterr()
    for planners, words in [("env_policies:bad", "policy env_policies:bad returned 'left': must be an integer candidate view index in 0..59 (a policy "
                             "returns a candidate view index or a (3,) direction)"),
                            ("env_policies:absent", "env_policies has no function absent"),
                            ("no_such_module:act", "cannot import no_such_module (ModuleNotFoundError"),
                            ("missing.py:act", "no such file missing.py"),
                            (":act", "a policy is module:function")]:
        assert main(["evaluate", "--meshes", str(mesh_folder / "ring.obj"), "--planners", planners, "--scans", "2",
                     "--config", str(SMOKE), "--out", str(out), "--no-progress"]) == 2
        err = capsys.readouterr().err.strip()
        assert words in err and len(err.splitlines()) == 1, err
