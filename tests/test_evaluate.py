"""nbvtrain evaluate and its planners: the full command on two small meshes, blindness of the
robot's planners to the mesh, information gain against a slow sampled reference, start views
apart from generation's, separate random streams, the overlap of chosen poses, the summary."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from reference_infogain import sampled_scores

from nbvdata.cli import main as nbvdata_main
from nbvdata.core.config import ConfigError, SimConfig, load_config
from nbvdata.core.views import farthest_view, spread_view, view_sphere
from nbvdata.schema.shards import Shard, shard_files
from nbvdata.simulation.episode import Reconstruction, ViewCache, scene_rng, start_view
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.shapes import BUILTIN_SHAPES, builtin_object
from nbvdata.simulation.sources import MeshSource, mesh_sources
from nbvtrain.cli import main
from nbvtrain.evaluation.evaluate import (EvaluationReport, coverage_table, evaluate, front_view, plot_coverage,
                                          reconstruct, start_views, summary_markdown)
from nbvtrain.networks.config import TrainConfig
from nbvtrain.networks.models import build_model
from nbvtrain.networks.train import save_training_state
from nbvtrain.networks.trained_scene import scene_record
from nbvtrain.planners import (PLANNERS, READS, FarthestPlanner, InfoGainPlanner, Observation, OraclePlanner, Planner,
                               RandomPlanner, build_planners, planner_table)

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "configs" / "smoke.yaml"


@pytest.fixture(scope="module")
def config() -> SimConfig:
    return load_config(SimConfig, SMOKE)


@pytest.fixture(scope="module")
def meshes(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("meshes")
    for name in ("mug", "ring"):
        BUILTIN_SHAPES[name]().export(folder / f"{name}.obj")
    return folder


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory, config) -> dict[str, Path]:
    """Untrained (seeded) networks saved as nbvtrain checkpoints, trained in the smoke scene:
    the planners' interface only."""
    folder = tmp_path_factory.mktemp("checkpoints")
    units = view_sphere(config.views).unit_positions
    paths = {}
    for name in ("nbvnet-3-3", "nbvnet-class", "nbvscore-3"):
        torch.manual_seed(0)
        model = build_model(name, views=units if name == "nbvscore-3" else None)
        paths[name] = folder / f"{name}.pt"
        save_training_state(paths[name], model, torch.optim.Adam(model.parameters()), TrainConfig(model=name), [], 0,
                            0.4, scene_record(config), units)
    paths.update(_cover_models(folder, config))
    return paths


def _cover_models(folder: Path, config: SimConfig) -> dict[str, Path]:
    """An untrained scvp-net of the scene's views, and a cover-gbm and a surface-gbm of a few trees
    on random rows: the cover and expected-surface planners' interface only."""
    from nbvdata.simulation.viewfeatures import BASE
    from nbvtrain.ranking._lightgbm import lightgbm
    from nbvtrain.ranking.covermodel import CoverModel
    from nbvtrain.ranking.covernet import CoverNetConfig, network, save_covernet
    from nbvtrain.ranking.surfaceprior import VOXEL_FEATURES, SurfacePrior

    torch.manual_seed(0)
    views = view_sphere(config.views).positions
    save_covernet(folder / "covernet.pt", network(len(views), 2), CoverNetConfig(width=2), {"view_positions": views}, [])
    rng = np.random.default_rng(0)
    rows = rng.random((200, len(BASE))).astype(np.float32)
    booster = lightgbm.train({"objective": "binary", "verbosity": -1, "num_threads": 1, "min_data_in_leaf": 5},
                             lightgbm.Dataset(rows, label=(rows[:, 0] > 0.5).astype(int)), num_boost_round=3)
    grid = config.scene_grid
    CoverModel(booster, (4, 3), {"grid_size": grid.size, "grid_extent": float(grid.extent)}, 0.5, {}).save(
        folder / "cover.json")
    rows = rng.random((200, len(VOXEL_FEATURES))).astype(np.float32)
    booster = lightgbm.train({"objective": "binary", "verbosity": -1, "num_threads": 1, "min_data_in_leaf": 5},
                             lightgbm.Dataset(rows, label=(rows[:, 0] > 0.5).astype(int)), num_boost_round=3)
    SurfacePrior(booster, {"grid_size": grid.size, "grid_extent": float(grid.extent)}, 0.1, {}).save(
        folder / "surface.json")
    return {"cover": folder / "cover.json", "scvp-net": folder / "covernet.pt", "surface": folder / "surface.json"}


def _learned(checkpoints: dict[str, Path]) -> dict[str, Path]:
    """build_planners' checkpoints: task -> file."""
    return {"regression": checkpoints["nbvnet-3-3"], "classification": checkpoints["nbvnet-class"],
            "scores": checkpoints["nbvscore-3"], "cover": checkpoints["cover"], "scvp-net": checkpoints["scvp-net"],
            "surface": checkpoints["surface"]}


@pytest.fixture(scope="module")
def scene(config) -> Scene:
    obj = builtin_object("mug", config.mesh)
    return Scene.build(obj, config, scene_rng(0, obj.mesh_id))


def _rows(path: Path) -> list[dict]:
    with open(path) as handle:
        return list(csv.DictReader(handle))


def test_full_command_on_two_meshes(meshes, checkpoints, tmp_path, capsys):
    out = tmp_path / "eval"
    assert main(["evaluate", "--meshes", str(meshes), "--checkpoint", str(checkpoints["nbvnet-3-3"]),
                 "--class-checkpoint", str(checkpoints["nbvnet-class"]), "--score-checkpoint",
                 str(checkpoints["nbvscore-3"]), "--scans", "5", "--random-starts", "2",
                 "--config", str(SMOKE), "--out", str(out), "--no-progress"]) == 0
    assert "54 reconstructions" in capsys.readouterr().out
    rows = _rows(out / "coverage.csv")
    planners = ["scores", "regression", "classification", "infogain", "oracle", "setcover", "random", "farthest",
                "viewrank"]
    assert len(rows) == 2 * len(planners) * 3 * 5  # meshes x planners x starts x scans
    assert {r["planner"] for r in rows} == set(planners) and {r["mesh"] for r in rows} == {"mug", "ring"}
    runs: dict[tuple, list[dict]] = {}
    for row in rows:
        runs.setdefault((row["mesh"], row["planner"], row["start"]), []).append(row)
    for (mesh, planner, start), run in runs.items():
        coverage = [float(r["coverage"]) for r in run]
        assert [int(r["scan"]) for r in run] == [1, 2, 3, 4, 5]
        assert all(0 < c <= 1 for c in coverage) and coverage == sorted(coverage)  # never decreases
        assert float(run[0]["seconds"]) == 0 and all(float(r["seconds"]) > 0 for r in run[1:])
        radius = np.linalg.norm([[float(r[k]) for k in "xyz"] for r in run], axis=1)
        assert np.allclose(radius, 0.4, atol=1e-6)  # every pose on the view sphere
        # every planner starts from the same view, so the first scan gives the same coverage
        assert run[0]["coverage"] == runs[(mesh, "random", start)][0]["coverage"]
        oracle = float(runs[(mesh, "oracle", start)][-1]["coverage"])
        assert oracle >= float(runs[(mesh, "random", start)][-1]["coverage"])
    summary = (out / "summary.md").read_text()
    assert ("| object | scores | regression | classification | infogain | oracle | setcover | random | farthest | "
            "viewrank |") in summary
    assert "| **mean** |" in summary and "**" in summary.split("| mug |")[1].splitlines()[0]
    assert "| infogain |" in summary.split("Time per NBV")[1]
    assert "| planner | decisions | overlap under the rule | no valid candidate view |" in summary
    for run in runs.values():
        assert run[0]["overlap"] == run[0]["valid_views"] == ""  # the start is no decision
        assert all(0 <= float(r["overlap"]) <= 1 and int(r["valid_views"]) >= 0 for r in run[1:])
    assert (out / "plots" / "mug.png").stat().st_size > 5000 and (out / "plots" / "ring.png").exists()
    assert "scans: 5" in (out / "config.yaml").read_text()


def _without_timings(out: Path) -> tuple[list[dict], str]:
    """coverage.csv's rows less the seconds column, and summary.md less its time-per-NBV table."""
    rows = [{key: value for key, value in row.items() if key != "seconds"} for row in _rows(out / "coverage.csv")]
    summary = (out / "summary.md").read_text()
    before, after = summary.split("Time per NBV")
    return rows, before + after[after.index("Overlap rule"):]


def test_two_workers_give_the_same_outputs_as_one(meshes, checkpoints, tmp_path, capsys):
    (meshes / "broken.obj").write_text("not a mesh\n")  # a failure among them keeps its place too
    try:
        outputs = {}
        for workers in ("1", "2"):
            out = tmp_path / workers
            assert main(["evaluate", "--meshes", str(meshes), "--checkpoint", str(checkpoints["nbvnet-3-3"]),
                         "--class-checkpoint", str(checkpoints["nbvnet-class"]), "--score-checkpoint",
                         str(checkpoints["nbvscore-3"]), "--scans", "4", "--random-starts", "1",
                         "--config", str(SMOKE), "--out", str(out), "--no-progress", "--workers", workers]) == 1
            outputs[workers] = _without_timings(out) + ((out / "failures.tsv").read_text(),)
    finally:
        (meshes / "broken.obj").unlink()
    rows = outputs["1"][0]
    assert len(rows) == 2 * 9 * 2 * 4 and {r["mesh"] for r in rows} == {"mug", "ring"}  # meshes x planners x starts x scans
    assert outputs["2"] == outputs["1"]


def test_planners_without_checkpoints_are_skipped_and_errors_exit_2(meshes, checkpoints, tmp_path, capsys):
    out = tmp_path / "eval"
    assert main(["evaluate", "--meshes", str(meshes / "mug.obj"), "--planners", "classification,random", "--scans",
                 "2", "--config", str(SMOKE), "--out", str(out), "--no-progress"]) == 0
    assert "classification: skipped, no classification model is released" in capsys.readouterr().err
    assert {r["planner"] for r in _rows(out / "coverage.csv")} == {"random"}
    assert "classification: skipped" in (out / "summary.md").read_text()
    for argv, message in [
        (["--planners", "oracle,astar"], "--planners 'oracle,astar': choose from"),
        (["--planners", "classification"], "no planner left to run"),
        (["--planners", "classification", "--class-checkpoint", str(checkpoints["nbvnet-3-3"])],
         "a regression network (nbvnet-3-3); pass it with --checkpoint"),
    ]:
        assert main(["evaluate", "--meshes", str(meshes), "--config", str(SMOKE), "--out", str(out), *argv]) == 2
        assert message in capsys.readouterr().err
    with pytest.raises(SystemExit) as done:  # refused by the option's type, before anything runs
        main(["evaluate", "--meshes", str(meshes), "--out", str(out), "--scans", "1"])
    assert done.value.code == 2 and "argument --scans: must be a whole number >= 2, not '1'" in capsys.readouterr().err


def test_random_starts_count_besides_the_front_one_and_starts_is_refused_in_one_line(meshes, tmp_path, capsys):
    """evaluate --random-starts K runs K + 1 starts (front + K random); --starts, which benchmark uses for
    every start counted, is refused on evaluate in one line naming --random-starts."""
    out = tmp_path / "eval"
    assert main(["evaluate", "--meshes", str(meshes / "mug.obj"), "--planners", "random", "--scans", "2",
                 "--random-starts", "1", "--no-floors", "--config", str(SMOKE), "--out", str(out),
                 "--no-progress"]) == 0
    assert {row["start"] for row in _rows(out / "coverage.csv")} == {"0", "1"}
    assert "random_starts: 1" in (out / "config.yaml").read_text()
    capsys.readouterr()
    with pytest.raises(SystemExit) as done:
        main(["evaluate", "--meshes", str(meshes), "--starts", "1"])
    error = capsys.readouterr().err.strip()
    assert done.value.code == 2 and len(error.splitlines()) == 1
    assert "--starts 1: evaluate's option is --random-starts K" in error and "--starts 1 was --random-starts 1" in error


def shapenet_like(folder: Path) -> Path:
    """Two meshes of one file name in their own folders (ShapeNet's CAT/ID/models/model_normalized.obj)
    and one of its own name."""
    for shape, model in (("mug", "02/aa/models"), ("ring", "02/bb/models")):
        (folder / model).mkdir(parents=True)
        BUILTIN_SHAPES[shape]().export(folder / model / "model_normalized.obj")
    BUILTIN_SHAPES["pill"]().export(folder / "pill.obj")
    return folder


def test_meshes_of_one_file_name_are_named_by_their_path(tmp_path):
    sources, _ = mesh_sources(shapenet_like(tmp_path))
    assert sorted(source.title for source in sources) == ["02/aa/models/model_normalized.obj",
                                                          "02/bb/models/model_normalized.obj", "pill"]
    assert {source.recorded for source in sources} == {"02/aa/models/model_normalized.obj",  # what shards record
                                                       "02/bb/models/model_normalized.obj", "pill.obj"}
    listed = tmp_path / "list.txt"
    listed.write_text("02/aa/models/model_normalized.obj\npill.obj\n")
    assert [source.title for source in mesh_sources(listed)[0]] == ["model_normalized", "pill"]  # no collision


def test_evaluate_tells_meshes_of_one_file_name_apart(tmp_path, capsys):
    out = tmp_path / "eval"
    assert main(["evaluate", "--meshes", str(shapenet_like(tmp_path / "meshes")), "--planners", "farthest",
                 "--scans", "2", "--no-floors", "--config", str(SMOKE), "--out", str(out), "--no-progress"]) == 0
    named = {"02/aa/models/model_normalized.obj", "02/bb/models/model_normalized.obj", "pill"}
    assert {row["mesh"] for row in _rows(out / "coverage.csv")} == named
    summary = (out / "summary.md").read_text()
    assert all(f"| {name} |" in summary for name in named) and "3 objects" in summary
    assert all((out / "plots" / f"{name}.png").is_file() for name in named)


def test_a_broken_mesh_is_reported_and_the_others_go_on(meshes, tmp_path, capsys):
    folder = tmp_path / "meshes"
    folder.mkdir()
    (folder / "mug.obj").write_bytes((meshes / "mug.obj").read_bytes())
    (folder / "broken.obj").write_text("v 0 0 0\nv 1 0 0\n")  # no faces
    out = tmp_path / "eval"
    assert main(["evaluate", "--meshes", str(folder), "--planners", "random", "--scans", "2", "--config", str(SMOKE),
                 "--out", str(out), "--no-progress"]) == 1
    printed = capsys.readouterr()
    assert len([line for line in (printed.out + printed.err).splitlines() if "broken.obj" in line]) == 1
    assert printed.err.count("broken.obj") == 1  # said once, the path not repeated in the reason
    header, *failures = (out / "failures.tsv").read_text().splitlines()
    assert header == "mesh\treason" and len(failures) == 1 and failures[0].split("\t")[0].endswith("broken.obj")
    assert {r["mesh"] for r in _rows(out / "coverage.csv")} == {"mug"}



def test_a_planner_that_raises_fails_its_mesh_and_the_others_go_on(meshes, tmp_path, capsys):
    policy = tmp_path / "fragile.py"
    policy.write_text("CALLS = []\n\n\ndef policy(observation):\n    CALLS.append(1)\n"
                      "    if len(CALLS) == 1:\n        raise ZeroDivisionError('a bug in the policy')\n"
                      "    return 0\n")
    out = tmp_path / "eval"
    assert main(["evaluate", "--meshes", str(meshes), "--planners", f"random,{policy}:policy", "--scans", "3",
                 "--config", str(SMOKE), "--workers", "1", "--out", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err
    header, *failures = (out / "failures.tsv").read_text().splitlines()
    assert len(failures) == 1 and failures[0].split("\t")[0].endswith("mug.obj")
    assert "ZeroDivisionError from start view" in failures[0] and "a bug in the policy" in failures[0]
    assert err.count("a bug in the policy") == 1
    rows = _rows(out / "coverage.csv")
    assert {r["mesh"] for r in rows} == {"ring"}  # the mug's random rows left out too: same meshes for all
    assert {r["planner"] for r in rows} == {"random", f"{policy}:policy"}

class Tripwire:
    """Wraps an object; while ``armed``, touching any of its attributes fails the test."""

    armed = False

    def __init__(self, target, name: str):
        self._target, self._name = target, name

    def __getattr__(self, attribute):
        if Tripwire.armed:
            raise AssertionError(f"a robot planner read {self._name}.{attribute}")
        return getattr(self._target, attribute)


class Cheat(Planner):
    """A planner that peeks at the simulation: the tripwire must catch it."""

    def __init__(self, scene: Scene):
        self.scene = scene

    def next_pose(self, observation, truth=None):
        return self.scene.views[int(np.argmax(self.scene.oracle.view_counts))]


def _run_guarded(config, scene, planners, meshes, monkeypatch):
    """Evaluate ``planners`` on a scene whose mesh, scanner, coverage and oracle are tripwired
    while a non-privileged planner decides."""
    guarded = Scene(config, Tripwire(scene.object, "object"), scene.views, Tripwire(scene.scanner, "scanner"),
                    Tripwire(scene.coverage, "coverage"), Tripwire(scene.oracle, "oracle"))
    for planner in planners:
        if isinstance(planner, Cheat):
            planner.scene = guarded
        choose = planner.next_pose

        def armed(observation, truth=None, choose=choose, privileged=planner.privileged):
            Tripwire.armed = not privileged
            try:
                return choose(observation, truth)
            finally:
                Tripwire.armed = False

        planner.next_pose = armed
    source = MeshSource("mug.obj", "0" * 64, meshes / "mug.obj")
    with monkeypatch.context() as patch:
        patch.setattr(Scene, "build", classmethod(lambda cls, *args, **kwargs: guarded))
        return evaluate([source], planners, config, scans=3)


def test_robot_planners_never_read_the_mesh(config, scene, checkpoints, meshes, monkeypatch):
    """Every registered planner: those that do not read the scene (``PlannerKind.reads``) are not
    privileged and never touch the simulation while they decide; those that do are privileged."""
    planners, skipped = build_planners(list(PLANNERS), config, scene.views, _learned(checkpoints))

    def kind(planner) -> str:  # "scores", "hybrid-w1" -> "hybrid", "proximity-count"
        return max((name for name in PLANNERS if planner.name == name or planner.name.startswith(name + "-")), key=len)

    assert not skipped and {kind(p) for p in planners} == set(PLANNERS)
    for planner in planners:
        assert planner.privileged == ("scene" in PLANNERS[kind(planner)].reads), planner.name
    report = _run_guarded(config, scene, planners, meshes, monkeypatch)
    assert len(report.rows) == len(planners) * 3 and not report.failures
    caught = _run_guarded(config, scene, [Cheat(scene)], meshes, monkeypatch)  # the mesh fails, the run goes on
    assert not caught.rows and len(caught.failures) == 1
    assert "raised AssertionError" in caught.failures[0][1] and "a robot planner read oracle.view_counts" in caught.failures[0][1]


def test_the_registry_describes_every_planner_and_the_docs_table_is_made_from_it(capsys):
    for name, kind in PLANNERS.items():
        assert kind.name == name and kind.reads and set(kind.reads) <= set(READS) and kind.chooses
    page = (ROOT / "docs" / "evaluation.md").read_text()
    assert "\n".join(planner_table()) in page, "docs/evaluation.md: paste nbvtrain.planners.planner_table() again"
    with pytest.raises(SystemExit):
        main(["evaluate", "--help"])
    helped = " ".join(capsys.readouterr().out.split())
    assert all(name in helped for name in PLANNERS)


def test_an_unknown_planner_lists_the_registered_ones(config, scene):
    with pytest.raises(ConfigError, match="unknown planner 'oracel': choose from " + ", ".join(PLANNERS)):
        build_planners(["oracel"], config, scene.views, {})


def test_scanning_a_candidate_pose_live_equals_the_cached_view(scene):
    cached, live = (Reconstruction(scene, ViewCache(scene), np.random.default_rng(0)),
                    Reconstruction(scene, None, np.random.default_rng(0)))
    for view in (3, 17, 40):
        cached.scan(view)
        live.scan_pose(scene.views[view])
    assert np.array_equal(cached.grid.log_odds, live.grid.log_odds) and np.array_equal(cached.covered, live.covered)


def test_oracle_and_random_planners(scene, config):
    state = Reconstruction(scene, None, np.random.default_rng(0))
    state.scan(5)
    observation = Observation(state.grid.probabilities(), (scene.views[5],))
    pose = OraclePlanner(scene.views, config.oracle.min_overlap).next_pose(observation, state)
    scores = scene.oracle.score(state.covered)
    assert np.array_equal(pose.position, scene.views.positions[scores.best(config.oracle.min_overlap)])
    planner = RandomPlanner(scene.views)
    picks = []
    for _ in range(2):
        planner.start(7)
        picks.append([tuple(planner.next_pose(observation).position) for _ in range(5)])
    assert picks[0] == picks[1] and len(set(picks[0])) > 1


def test_farthest_takes_the_unscanned_view_farthest_from_every_scan():
    """Against the angles themselves (arctan2 of cross and dot): the view picked has the largest
    angle to its nearest scanned pose; never a scanned view; any radius; ties to the lowest index."""
    views = view_sphere(load_config(SimConfig).views)
    units = views.unit_positions
    scanned = [int(np.random.default_rng(2).integers(len(units)))]
    for _ in range(12):
        positions = units[scanned] * 0.4
        pick = farthest_view(units, positions)
        angles = np.array([[np.arctan2(np.linalg.norm(np.cross(u, p)), u @ p) for p in units[scanned]] for u in units])
        nearest = angles.min(axis=1)
        nearest[scanned] = -1.0
        assert pick not in scanned and nearest[pick] >= nearest.max() - 1e-9
        assert farthest_view(units, positions * 7.5) == pick  # only directions count
        scanned.append(pick)
    assert len(set(scanned)) == len(scanned)
    axes = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0], [-1.0, 0, 0]])
    assert farthest_view(axes, np.array([[2.0, 0, 0]])) == 3  # the opposite view
    assert farthest_view(axes, np.array([[1.0, 0, 0], [-1.0, 0, 0]])) == 1  # 1 and 2 tie: the lower
    assert farthest_view(axes, np.zeros((0, 3))) == 0
    planner = FarthestPlanner(views)
    observation = Observation(np.full((32, 32, 32), 0.5, np.float32), tuple(views[i] for i in scanned[:3]))
    assert np.array_equal(planner.next_pose(observation).position, views.positions[scanned[3]])


def test_evaluation_starts_are_not_generation_starts(meshes, tmp_path):
    """Same meshes, config and seed: no random evaluation start is the start of a generation run."""
    shards = tmp_path / "shards"
    assert nbvdata_main(["generate", "--meshes", str(meshes), "--config", str(SMOKE), "--out", str(shards),
                         "--no-progress"]) == 0
    generated = {}
    for path in shard_files([shards]):
        with Shard(path) as shard:
            first = shard["step"] == 1
            mesh = shard.info.meshes[0]["source"].removesuffix(".obj")
            generated.setdefault(mesh, set()).update(shard["last_view"][first].tolist())
    assert {mesh: len(views) for mesh, views in generated.items()} == {"mug": 3, "ring": 3}  # runs_per_mesh
    out = tmp_path / "eval"
    assert main(["evaluate", "--meshes", str(meshes), "--planners", "random", "--scans", "2", "--random-starts", "8",
                 "--config", str(SMOKE), "--out", str(out), "--no-progress"]) == 0
    starts = {}
    for row in _rows(out / "coverage.csv"):
        if int(row["start"]) > 0:
            starts.setdefault(row["mesh"], set()).add(int(row["start_view"]))
    for mesh, views in starts.items():
        assert len(views) == 8 and not views & generated[mesh], mesh


def test_start_views_avoid_every_generation_start(scene):
    mesh_id, count = scene.object.mesh_id, len(scene.views)
    for seed in range(4):
        taken = {start_view(seed, mesh_id, count, run) for run in range(40)}  # 40 of the 60 views
        starts = start_views(scene, mesh_id, 12, seed, generation_runs=40)
        assert starts[0] == front_view(scene) and len(set(starts)) == 13 and not set(starts[1:]) & taken
    # no generation run: every view but the front one, each once
    others = start_views(scene, mesh_id, count - 1, 0, generation_runs=0)[1:]
    assert set(others) == set(range(count)) - {front_view(scene)}
    # every view started a generation run: then any view will do, still from the evaluation's stream
    assert len(set(start_views(scene, mesh_id, 5, 0, generation_runs=100)[1:])) == 5


def test_random_choices_and_sensor_noise_have_separate_streams(config, scene):
    noisy_config = load_config(SimConfig, SMOKE, ["sensor.noise_std=0.002"])
    noisy = Scene.build(scene.object, noisy_config, scene_rng(0, scene.object.mesh_id))
    poses = [[(r["x"], r["y"], r["z"]) for r in reconstruct(s, RandomPlanner(s.views), 3, 6, seed=11)]
             for s in (scene, noisy)]
    assert poses[0] == poses[1]  # the random planner's choices do not depend on the noise

    class Spy(Planner):
        """Compares the planner's stream with the sensor noise's (unused by this noise-free scene)."""

        privileged = True

        def start(self, seed):
            self.draws = np.random.default_rng(seed).random(4)

        def next_pose(self, observation, truth=None):
            self.noise_draws = truth.rng.random(4)
            return truth.scene.views[0]

    spy = Spy()
    reconstruct(scene, spy, 3, 2, seed=11)
    assert not np.array_equal(spy.draws, spy.noise_draws)


def test_chosen_pose_overlap_is_the_oracles(scene, config):
    """Noise-free, a candidate pose's overlap is the oracle's overlap(v) at that state, and the
    oracle breaks the rule only where no candidate view passes it."""

    class Fixed(Planner):
        def __init__(self, views):
            self.views, self.order = views, iter([])

        def start(self, seed):
            self.order = iter([40, 41, 17, 3, 55])

        def next_pose(self, observation, truth=None):
            return scene.views[next(self.order)]

    rows = reconstruct(scene, Fixed(scene.views), 5, 6, seed=0)
    state = Reconstruction(scene, ViewCache(scene), np.random.default_rng(0))
    state.scan(5)
    min_overlap = config.oracle.min_overlap
    for view, row in zip([40, 41, 17, 3, 55], rows[1:]):
        scores = scene.oracle.score(state.covered)
        assert row["overlap"] == pytest.approx(scores.overlaps[view], abs=1e-12)
        assert row["valid_views"] == int(((scores.overlaps >= min_overlap) & (scores.new > 0)).sum())
        state.scan(view)
    assert rows[0]["overlap"] is None and min(r["overlap"] for r in rows[1:]) < min_overlap  # some break it
    for first in (0, 20, 40):
        oracle_rows = reconstruct(scene, OraclePlanner(scene.views, min_overlap), first, 10, seed=0)
        assert all(r["valid_views"] == 0 for r in oracle_rows[1:] if r["overlap"] < min_overlap)


def _row(mesh, planner, start, scan, coverage, overlap=None, valid_views=None):
    return {"mesh": mesh, "planner": planner, "start": start, "start_view": 0, "scan": scan, "coverage": coverage,
            "observable_coverage": coverage, "seconds": 0.001, "x": 0.0, "y": 0.0, "z": 0.4, "overlap": overlap,
            "valid_views": valid_views}


def _finals(table: list[tuple[str, tuple, tuple, tuple]]) -> list[dict]:
    """Rows of two starts x two scans per planner: (planner, final coverages, overlaps, valid views)."""
    rows = []
    for planner, finals, overlaps, valid in table:
        for start, final in enumerate(finals):
            rows += [_row("mug", planner, start, 1, 0.5),
                     _row("mug", planner, start, 2, final, overlaps[start], valid[start])]
    return rows


def test_summary_bolds_every_tie():
    rows = _finals([("a", (0.9791, 0.9794), (0.5, 0.1), (3, 0)),  # 97.9 as printed
                    ("b", (0.9788, 0.9788), (0.05, 0.3), (2, 2)),  # 97.9 as well, a little less
                    ("c", (0.90, 0.91), (0.3, 0.3), (1, 1))])
    (line,) = [row for row in coverage_table(rows, ["a", "b", "c"], "coverage") if row.startswith("| mug")]
    assert line == "| mug | **97.9 ± 0.0** | **97.9 ± 0.0** | 90.5 ± 0.5 |"


def test_summary_counts_overlap_breaks():
    rows = _finals([("a", (0.9, 0.9), (0.5, 0.1), (3, 0)), ("b", (0.9, 0.9), (0.05, 0.3), (2, 2)),
                    ("c", (0.9, 0.9), (0.3, 0.2), (1, 1))])  # 0.2 is not under the rule
    summary = summary_markdown(EvaluationReport(rows, min_overlap=0.2), ["a", "b", "c"], [])
    assert "| a | 2 | 50.0 % (1) | 50.0 % (1) |" in summary and "| b | 2 | 50.0 % (1) | 0.0 % (0) |" in summary
    assert "| c | 2 | 0.0 % (0) | 0.0 % (0) |" in summary and "under 20 %" in summary


def test_plots_tick_whole_scans(tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    ticks, save = [], Figure.savefig

    def spy(figure, *args, **kwargs):
        low, high = figure.axes[0].get_xlim()
        ticks.append([t for t in figure.axes[0].get_xticks() if low <= t <= high])
        return save(figure, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", spy)
    rows = [_row("mug", "a", 0, scan, 0.2 * scan) for scan in (1, 2, 3)]
    plot_coverage(rows, tmp_path)
    assert ticks and ticks[0] == [1.0, 2.0, 3.0]


def test_information_gain_agrees_with_a_sampled_walk(scene, config):
    planner = InfoGainPlanner(config.scene_grid, config.sensor, config.views.radius, config.mesh.object_size,
                              config.oracle.min_overlap)
    state = Reconstruction(scene, None, np.random.default_rng(0))
    for view in (0, 30):
        state.scan(view)
    probabilities = state.grid.probabilities()
    scores = planner.scores(probabilities)
    rays = np.arange(0, planner._ends.shape[1], 7)  # a seventh of the rays: the reference is slow
    from nbvdata.simulation.grid import ray_information

    for view in (0, 9, 19):
        information, known, unknown = sampled_scores(planner, probabilities, view, rays)
        ends = np.ascontiguousarray(planner._ends[view:view + 1, rays])
        fast = np.zeros(ends.shape[:2])
        first = np.zeros(ends.shape[:2], dtype=np.int8)
        ray_information(planner._origins[view:view + 1], ends, probabilities, config.scene_grid.resolution,
                         -(config.grid.size // 2), *planner._box, *planner.unknown, planner._scratch, fast, first)
        assert fast.sum() == pytest.approx(information, rel=0.01)  # sampling may miss a clipped corner
        assert information > 0
        assert abs(int((first == 1).sum()) - known) <= 2 and abs(int((first == 2).sum()) - unknown) <= 2
    assert scores.information.shape == (20,) and (scores.overlaps >= 0).all() and (scores.overlaps <= 1).all()


def test_information_gain_properties(config):
    planner = InfoGainPlanner(config.scene_grid, config.sensor, config.views.radius, config.mesh.object_size,
                              config.oracle.min_overlap)
    n = config.grid.size
    unknown = planner.scores(np.full((n, n, n), 0.5, dtype=np.float32))
    assert (unknown.information > 0).all() and (unknown.known_rays == 0).all() and (unknown.overlaps == 0).all()
    free = planner.scores(np.full((n, n, n), 0.3, dtype=np.float32))
    assert (free.information == 0).all() and (free.known_rays + free.unknown_rays == 0).all()
    # an occupied shell around an unknown core: the core is hidden, every view meets known surface
    shell = np.full((n, n, n), 0.3, dtype=np.float32)
    shell[8:24, 8:24, 8:24] = 0.9
    shell[10:22, 10:22, 10:22] = 0.5
    hidden = planner.scores(shell)
    assert (hidden.information == 0).all() and (hidden.overlaps == 1).all()
    # leave one side of the shell unknown: the views facing it gain the most
    opened = shell.copy()
    opened[8:24, 8:24, 22:24] = 0.5  # the top face
    scores = planner.scores(opened)
    best = int(np.argmax(scores.information))
    assert planner.views.positions[best][2] > 0.3  # a view from high above
    assert planner.best_view(opened) == int(np.argmax(np.where(scores.overlaps >= config.oracle.min_overlap,
                                                               scores.information, -1)))


def _positions(rows: list[dict]) -> list[tuple]:
    return [tuple(np.round([row[k] for k in "xyz"], 9)) for row in rows]


def test_the_scores_planner_never_returns_a_scanned_view(scene, config, checkpoints):
    (planner,), _ = build_planners(["scores"], config, scene.views, _learned(checkpoints))
    candidates = {tuple(np.round(p, 9)) for p in scene.views.positions}
    for first in (0, 17, 42):
        positions = _positions(reconstruct(scene, planner, first, 15, seed=first))
        assert len(set(positions)) == 15 and set(positions) <= candidates


def test_no_stall_falls_back_to_an_unscanned_view(scene, config, checkpoints):
    """An untrained regression network answers about the same direction in every state, so it
    repeats its pose; with --no-stall each pose marks a new candidate view."""
    planners, _ = build_planners(["regression"], config, scene.views, _learned(checkpoints))
    units = scene.views.unit_positions

    def nearest(rows):
        return [int(np.argmax(units @ (p / np.linalg.norm(p)))) for p in np.array(_positions(rows))]

    stalled = _positions(reconstruct(scene, planners[0], 3, 8, seed=0))
    assert len(set(nearest(reconstruct(scene, planners[0], 3, 8, seed=0)))) < 8
    for name in ("regression", "classification"):
        (planner,), _ = build_planners([name], config, scene.views, _learned(checkpoints), no_stall=True)
        assert planner.name == f"{name}-nostall"
        assert len(set(nearest(reconstruct(scene, planner, 3, 8, seed=0)))) == 8
    # where the network's pose repeats nothing, --no-stall keeps it as it is
    answer = np.array(stalled[1]) / np.linalg.norm(stalled[1])
    start = int(np.argmin(units @ answer))  # the candidate farthest from the network's answer
    plain = _positions(reconstruct(scene, planners[0], start, 2, seed=0))[1]
    assert int(np.argmax(units @ (np.array(plain) / np.linalg.norm(plain)))) != start
    (kept,), _ = build_planners(["regression"], config, scene.views, _learned(checkpoints), no_stall=True)
    assert _positions(reconstruct(scene, kept, start, 2, seed=0))[1] == plain


def test_spread_takes_the_answer_away_from_the_scans():
    """spread_view against the plain formula: weight 0 is the unscanned view nearest the answer,
    a large weight the farthest view; never a scanned view; the answer's length does not count."""
    units = view_sphere(load_config(SimConfig).views).unit_positions
    rng = np.random.default_rng(4)
    for _ in range(5):
        scanned = rng.choice(len(units), size=int(rng.integers(1, 6)), replace=False)
        positions, answer = units[scanned] * 0.4, rng.normal(size=3)
        free = np.ones(len(units), dtype=bool)
        free[scanned] = False
        for weight in (0.0, 0.5, 2.0):
            score = units @ (answer / np.linalg.norm(answer)) - weight * (units @ units[scanned].T).max(axis=1)
            pick = spread_view(units, positions, answer * 3.0, weight)
            assert free[pick] and score[pick] >= score[free].max() - 1e-9
        assert spread_view(units, positions, answer, 1e9) == farthest_view(units, positions)
    assert spread_view(units, units * 0.4, answer, 1.0) == 0  # every view scanned


def test_spread_planners_never_repeat_and_follow_the_formula(scene, config, checkpoints):
    """--spread W: a regression or classification planner's pose is the candidate view spread_view
    picks for its network's answer and the poses scanned so far, so it never repeats a view."""
    units = scene.views.unit_positions
    for name in ("regression", "classification"):
        (planner,), _ = build_planners([name], config, scene.views, _learned(checkpoints), spread=1.0)
        assert planner.name == f"{name}-spread1"
        rows = reconstruct(scene, planner, 3, 8, seed=0)
        chosen = [int(np.argmax(units @ (p / np.linalg.norm(p)))) for p in np.array(_positions(rows))]
        assert len(set(chosen)) == 8
        poses = tuple(scene.views[i] for i in chosen[:3])
        grid = np.full((scene.config.grid.size,) * 3, 0.5, dtype=np.float32)
        (answer,) = planner.predictor.predict(grid)
        expected = spread_view(units, np.array([p.position for p in poses]), answer.direction, 1.0)
        assert np.array_equal(planner.next_pose(Observation(grid, poses)).position, scene.views.positions[expected])
    (scores,), _ = build_planners(["scores"], config, scene.views, _learned(checkpoints), spread=1.0)
    assert scores.name == "scores" and scores.spread is None  # the score network has its own view state


def test_spread_on_the_command_line(meshes, checkpoints, tmp_path, capsys):
    common = ["evaluate", "--meshes", str(meshes), "--planners", "regression,farthest", "--checkpoint",
              str(checkpoints["nbvnet-3-3"]), "--scans", "2", "--config", str(SMOKE), "--no-progress"]
    assert main([*common, "--spread", "1", "--no-stall", "--out", str(tmp_path / "both")]) == 2
    assert "--spread never repeats a view already: drop --no-stall" in capsys.readouterr().err
    assert not (tmp_path / "both").exists()
    assert main([*common, "--spread", "0.5", "--out", str(tmp_path / "spread")]) == 0
    assert {r["planner"] for r in _rows(tmp_path / "spread" / "coverage.csv")} == {"regression-spread0.5", "farthest"}
    settings = yaml.safe_load((tmp_path / "spread" / "config.yaml").read_text())["evaluate"]
    assert settings["spread"] == 0.5 and settings["planners"] == ["regression-spread0.5", "farthest"]


def test_a_checkpoint_of_another_scene_is_refused(meshes, checkpoints, tmp_path, capsys):
    for planner, flag, name in (("scores", "--score-checkpoint", "nbvscore-3"),
                                ("regression", "--checkpoint", "nbvnet-3-3")):
        assert main(["evaluate", "--meshes", str(meshes / "mug.obj"), "--planners", planner, flag,
                     str(checkpoints[name]), "--config", str(SMOKE), "--set", "views.count=40", "--scans", "2",
                     "--out", str(tmp_path / "eval"), "--no-progress"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "trained with other settings than this run's: views_count 60 " \
            "(the run has 40)" in err, err
    assert main(["evaluate", "--meshes", str(meshes / "mug.obj"), "--planners", "regression", "--checkpoint",
                 str(checkpoints["nbvnet-3-3"]), "--config", str(SMOKE), "--set", "mesh.object_size=0.2",
                 "--scans", "2", "--out", str(tmp_path / "eval"), "--no-progress"]) == 2
    assert "grid_extent" in capsys.readouterr().err
