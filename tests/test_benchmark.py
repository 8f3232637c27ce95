"""``nbvtrain benchmark``: the protocols as data, the metrics on hand-made cases and against brute
force, the same bytes for one and two workers, and bad input in one line."""

import csv
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import SHARED, need

from nbvdata.core.config import ConfigError, SimConfig, ViewConfig, load_config
from nbvdata.core.layout_tammes import tammes_128
from nbvdata.core.views import view_sphere
from nbvdata.simulation.episode import scene_rng
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.shapes import BUILTIN_SHAPES, builtin_object
from nbvtrain.cli import main
from nbvtrain.evaluation.benchmark import (PROTOCOLS, Protocol, RunMeasure, SurfaceMeasure, auc, load_protocol,
                                           protocol_names, scans_to)

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["sensor.width=44", "sensor.height=36", "coverage.points=2000"]


def test_the_shipped_protocols_load_and_say_their_budgets():
    assert protocol_names() == ["objview", "paper", "pc-nbv", "scvp"]
    objview = load_protocol("objview")
    assert objview.budgets == {"K=5": 6, "K=30": 31} and objview.views == 31 and objview.snap
    assert objview.thresholds == (0.01, 0.02, 0.03)
    assert load_protocol("paper").budgets == {"10 scans": 10} and not load_protocol("paper").snap
    assert load_protocol(PROTOCOLS / "pc-nbv.yaml").settings == ("views.layout=pc-nbv-33", "views.count=33")


def test_tammes_128_is_the_anchors_directions_and_hemi_keeps_those_above():
    anchor = np.loadtxt(need(SHARED / "anchors" / "objview_tammes_128.txt"))
    assert np.allclose(tammes_128(), anchor, atol=1e-11)
    whole = view_sphere(ViewConfig(count=128, layout="tammes-128", radius=0.4))
    hemi = view_sphere(ViewConfig(count=128, layout="tammes-128", radius=0.4, reach="hemi"))
    assert np.allclose(whole.unit_positions, tammes_128()) and len(whole) == 128
    keep = tammes_128()[:, 2] >= 0
    assert keep.sum() == 64 and np.array_equal(hemi.positions, whole.positions[keep])


def test_tammes_directions_are_unit_without_the_anchor():
    directions = tammes_128()
    assert directions.shape == (128, 3) and np.allclose(np.linalg.norm(directions, axis=1), 1.0)
    assert len(np.unique(np.round(directions, 6), axis=0)) == 128


def test_auc_is_pc_nbvs_trapezoid_from_zero():
    """(c1 + ... + c9 + c10 / 2) / 10: a curve at 1 from the first view has 0.95."""
    assert auc(np.ones(10)) == pytest.approx(0.95)
    assert auc(np.array([0.5, 1.0])) == pytest.approx((0.5 + 0.5) / 2)
    assert auc(np.linspace(0.1, 1.0, 10)) == pytest.approx(np.trapezoid(np.r_[0, np.linspace(0.1, 1.0, 10)]) / 10)


def test_scans_to_reach_counts_the_start_and_says_none_when_never():
    observable = np.array([0.6, 0.85, 0.92, 0.96, 0.99])
    assert [scans_to(observable, t) for t in (0.5, 0.9, 0.95, 0.99, 0.999)] == [1, 3, 4, 5, None]


@pytest.fixture(scope="module")
def small_scene() -> Scene:
    config = load_config(SimConfig, None, ["views.layout=tammes-128", "views.count=128", *SMALL])
    obj = builtin_object("mug", config.mesh)
    return Scene.build(obj, config, scene_rng(0, obj.mesh_id))


def test_chamfer_and_coverage_at_thresholds_equal_brute_force(small_scene):
    """Three scans of the mug: every distance by a full pairwise matrix instead of k-d trees."""
    protocol = Protocol(name="t", thresholds=(0.02, 0.05), voxel=0.005)
    measure = SurfaceMeasure(small_scene, protocol)
    run = RunMeasure(measure)
    views = [0, 40, 99]
    for scan, view in enumerate(views, start=1):
        run.add(scan, small_scene.views[view])
    points = np.concatenate([small_scene.scanner.scan(small_scene.views[v], cloud=False).hit_points for v in views])
    reference = np.asarray(small_scene.coverage.points, dtype=np.float64)
    distances = np.sqrt(((reference[:, None] - points[None].astype(np.float64)) ** 2).sum(axis=2))  # (R, M)
    gt_to_obs = distances.min(axis=1)
    # the scanned points fused per voxel (their mean), then each fused point to the nearest reference point
    keys = np.floor(points.astype(np.float64) / measure.voxel).astype(np.int64)
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    fused = np.array([points[inverse.ravel() == k].astype(np.float64).mean(axis=0) for k in range(inverse.max() + 1)])
    obs_to_gt = np.sqrt(((fused[:, None] - reference[None]) ** 2).sum(axis=2)).min(axis=1)
    radius = small_scene.bounding_radius
    expected = ((gt_to_obs ** 2).mean() + (obs_to_gt ** 2).mean()) / radius ** 2
    assert run.chamfer() == pytest.approx(expected, rel=1e-5)
    for t in (0.02, 0.05):
        assert run.rows[-1][f"sc_{t:g}"] == pytest.approx((gt_to_obs < t * radius).mean())


def test_a_view_scanned_twice_adds_no_point(small_scene):
    measure = SurfaceMeasure(small_scene, Protocol(name="t"))
    once, twice = RunMeasure(measure), RunMeasure(measure)
    once.add(1, small_scene.views[3])
    for scan in (1, 2):
        twice.add(scan, small_scene.views[3])
    assert once.chamfer() == twice.chamfer()


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("corpus")
    for name in ("mug", "ring", "pill"):
        BUILTIN_SHAPES[name]().export(folder / f"{name}.obj")
    return folder


@pytest.fixture(scope="module")
def small_protocol(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("protocols") / "small.yaml"
    path.write_text(yaml.safe_dump({"name": "small", "settings": ["views.layout=pc-nbv-33", "views.count=33", *SMALL],
                                    "budgets": {"K=2": 3, "K=4": 5}, "thresholds": [0.02], "snap": True}))
    return path


PLANNERS = "oracle,setcover,farthest,random,infogain"


def _run(protocol: Path, corpus: Path, out: Path, *extra: str) -> int:
    return main(["benchmark", "--protocol", str(protocol), "--meshes", str(corpus), "--planners", PLANNERS,
                 "--starts", "2", "--out", str(out), "--no-progress", *extra])


def test_one_and_two_workers_write_the_same_bytes(small_protocol, corpus, tmp_path):
    assert _run(small_protocol, corpus, tmp_path / "one", "--workers", "1") == 0
    assert _run(small_protocol, corpus, tmp_path / "two", "--workers", "2") == 0
    for name in ("per_object.csv", "runs.csv", "coverage.csv", "floors.csv"):
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "two" / name).read_bytes(), name
    comparable = lambda path: path.read_text().split("## Time per decision")[0]  # noqa: E731
    assert comparable(tmp_path / "one" / "benchmark.md") == comparable(tmp_path / "two" / "benchmark.md")
    rows = list(csv.DictReader(open(tmp_path / "one" / "per_object.csv")))
    assert {row["budget"] for row in rows} == {"K=2", "K=4"} and len({row["mesh"] for row in rows}) == 3
    assert {row["planner"] for row in rows} == set(PLANNERS.split(","))
    oracle = [row for row in rows if row["planner"] == "oracle"]
    assert all(float(row["auc"]) > 0 and float(row["path_m"]) > 0 and float(row["chamfer"]) > 0 for row in oracle)
    md = (tmp_path / "one" / "benchmark.md").read_text()
    assert "Paired differences against `farthest`" in md and "AUC (%) by difficulty" in md
    assert "AUC difference against `farthest` by difficulty" in md
    assert {p.name for p in (tmp_path / "one" / "plots").iterdir()} == {"small-k-2.png", "small-k-4.png"}


def test_setcover_reaches_the_floor_and_travels_less_than_farthest(small_protocol, corpus, tmp_path):
    """Noise-free, the set-cover plan reaches all the observable surface in exactly the floor's views,
    and its shortest tour travels less than visiting views by angle."""
    protocol = tmp_path / "long.yaml"
    protocol.write_text(small_protocol.read_text().replace("K=4: 5", "K=30: 31"))
    assert _run(protocol, corpus, tmp_path / "out", "--planners", "setcover,farthest", "--reference", "farthest") == 0
    rows = list(csv.DictReader(open(tmp_path / "out" / "runs.csv")))
    floors = {(row["mesh"], row["start"]): 1 + int(row["cover_size"])
              for row in csv.DictReader(open(tmp_path / "out" / "floors.csv"))}
    for row in rows:
        if row["planner"] == "setcover" and row["budget"] == "K=30":
            assert int(row["scans_to_99"]) <= floors[(row["mesh"], row["start"])]
    paths = {planner: np.mean([float(r["path_m"]) for r in rows if r["planner"] == planner and r["budget"] == "K=30"])
             for planner in ("setcover", "farthest")}
    assert paths["setcover"] < paths["farthest"]


def test_a_planner_that_raises_on_one_object_fails_that_object_only(small_protocol, corpus, tmp_path, monkeypatch):
    import nbvtrain.planners as planners

    real = planners.FarthestPlanner.next_pose

    def fails_on_the_ring(self, observation, truth=None):
        if observation.probabilities is not None and (observation.probabilities > 0.5).sum() > 0 and \
                getattr(self, "_ring", False):
            raise ZeroDivisionError("on the ring")
        return real(self, observation, truth)

    monkeypatch.setattr(planners.FarthestPlanner, "next_pose", fails_on_the_ring)
    monkeypatch.setattr(planners.FarthestPlanner, "_ring", False, raising=False)
    import nbvtrain.evaluation.benchmark as bench

    build = bench.Scene.build

    def build_and_mark(obj, *args, **kwargs):
        planners.FarthestPlanner._ring = obj.source.startswith("ring")
        return build(obj, *args, **kwargs)

    monkeypatch.setattr(bench.Scene, "build", build_and_mark)
    assert _run(small_protocol, corpus, tmp_path / "out", "--workers", "1") == 1
    failures = (tmp_path / "out" / "failures.tsv").read_text()
    assert "ring.obj" in failures and "raised ZeroDivisionError" in failures
    rows = list(csv.DictReader(open(tmp_path / "out" / "per_object.csv")))
    assert {row["mesh"] for row in rows} == {"mug", "pill"}  # every planner on the common objects
    assert "on the ring" in (tmp_path / "out" / "tracebacks.txt").read_text()


@pytest.mark.parametrize("argv, words", [
    (["--protocol", "no-such"], "no such protocol; choose from objview, paper, pc-nbv, scvp"),
    (["--meshes", "/nonexistent/folder"], "no such folder"),
    (["--reference", "oracle", "--planners", "farthest,random"], "--reference oracle: not among --planners"),
    (["--planners", "oracel"], "--planners 'oracel': choose from"),
    (["--part", "val"], "--part val needs --manifest manifests/NAME-X.Y.Z.json"),
    (["--manifest", "manifests/train-meshes-1.6.0.json"], "--manifest needs --part val, test or train"),
])
def test_bad_arguments_are_one_line_and_exit_2(corpus, tmp_path, capsys, argv, words):
    base = ["benchmark", "--meshes", str(corpus), "--out", str(tmp_path / "out"), "--no-progress"]
    assert main([*base, *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("change, words", [
    ({"budgetz": {"K=1": 2}}, "unknown setting 'protocol.budgetz'; did you mean 'protocol.budgets'?"),
    ({"budgets": {"K=0": 0}}, "budgets={'K=0': 0}: give label: views scanned (an integer >= 1)"),
    ({"thresholds": [-0.01]}, "thresholds and voxel must be > 0"),
    ({"start": "left"}, "protocol.start='left': must be one of 'random', 'front'"),
])
def test_a_bad_protocol_file_is_one_line(small_protocol, corpus, tmp_path, capsys, change, words):
    data = yaml.safe_load(small_protocol.read_text()) | change
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    assert _run(bad, corpus, tmp_path / "out") == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1, err


def test_the_default_corpus_missing_is_one_line(tmp_path, capsys, monkeypatch):
    import nbvtrain.evaluation.benchmark as bench

    monkeypatch.setattr(bench, "BENCH_MESHES", tmp_path / "absent")
    assert main(["benchmark", "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    assert "the default is the bench corpus" in capsys.readouterr().err


def test_starts_and_budgets_must_be_positive(capsys):
    with pytest.raises(SystemExit) as stopped:
        main(["benchmark", "--starts", "0"])
    assert stopped.value.code == 2 and "--starts" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="at least one start view"):
        from nbvtrain.evaluation.benchmark import benchmark

        benchmark([], [], SimConfig(), Protocol(name="t"), starts=0)
    assert math.isfinite(load_protocol("scvp").voxel)


def test_a_travel_weight_of_zero_is_the_planners_own_choice_and_a_large_one_travels_less(small_protocol, corpus,
                                                                                          tmp_path):
    assert _run(small_protocol, corpus, tmp_path / "out", "--planners", "oracle,farthest", "--travel-weight",
                "0,5") == 0
    rows = list(csv.DictReader(open(tmp_path / "out" / "coverage.csv")))
    poses = lambda planner: [(r["mesh"], r["start"], r["scan"], r["x"], r["y"], r["z"])  # noqa: E731
                             for r in rows if r["planner"] == planner]
    assert poses("oracle") == poses("oracle-travel0") and poses("farthest") == poses("farthest-travel0")
    runs = list(csv.DictReader(open(tmp_path / "out" / "runs.csv")))
    path = lambda planner: np.mean([float(r["path_m"]) for r in runs if r["planner"] == planner])  # noqa: E731
    assert path("oracle-travel5") < path("oracle") and path("farthest-travel5") < path("farthest")


@pytest.mark.parametrize("weight", ["-1", "nan", "x"])
def test_a_bad_travel_weight_is_one_line(small_protocol, corpus, tmp_path, capsys, weight):
    assert _run(small_protocol, corpus, tmp_path / "out", "--travel-weight", weight) == 2
    err = capsys.readouterr().err.strip()
    assert "--travel-weight" in err and len(err.splitlines()) == 1 and not (tmp_path / "out").exists()


def _synthetic(objects: int, starts: int = 1) -> tuple:
    """A report of ``objects`` objects without simulating them: oracle 5 and scores 1 AUC points above
    farthest on every object (so every interval excludes 0), a 6-scan budget, farthest missing 95 %
    on the first object and every planner 99 % everywhere. (report, per-object rows)"""
    from nbvtrain.evaluation.benchmark import RUN_METRICS, BenchmarkReport
    from nbvtrain.evaluation.benchmark_report import per_object

    rng = np.random.default_rng(0)
    report = BenchmarkReport(Protocol(name="t", budgets={"6 scans": 6}), ["oracle", "scores", "farthest"])
    for mesh in range(objects):
        base = rng.uniform(0.6, 0.8)
        for planner, ahead in zip(report.planners, (0.05, 0.01, 0.0)):
            for start in range(starts):
                report.runs.append({"budget": "6 scans", "mesh": f"m{mesh}", "planner": planner, "start": start,
                                    "start_view": 0} | {m: base + ahead + rng.normal(0, 0.002) for m in RUN_METRICS}
                                   | {"scans_to_90": 3, "scans_to_95": None if (planner, mesh) == ("farthest", 0)
                                      else 5, "scans_to_99": None, "path_to_90": 0.5,
                                      "path_to_95": None if (planner, mesh) == ("farthest", 0) else 0.9,
                                      "path_to_99": None})
    return report, per_object(report)


def test_few_objects_give_figures_without_a_verdict_and_every_table_states_n():
    """Two objects: intervals that exclude 0 are given, but no difference is called separable and no
    planner ahead, and the top of benchmark.md says why; 30 objects decide."""
    from nbvtrain.evaluation.benchmark_report import summary_markdown
    from nbvtrain.evaluation.statistics import MIN_OBJECTS

    report, rows = _synthetic(2)
    md = summary_markdown(report, rows, "farthest", 0)
    top, body = md.split("## 6 scans")
    assert f"No verdicts: 2 objects, fewer than {MIN_OBJECTS}" in top
    assert ", yes |" not in body and ", no verdict |" in body
    assert "ahead of" not in body and "not separable" not in body and "(no verdict on 2 objects)" in body
    assert "| planner (n = 2 objects) |" in body and "| planner | n |" in body and "| scores | 2 |" in body
    assert "paired over the n = 2 objects" in body
    report, rows = _synthetic(MIN_OBJECTS + 10)
    md = summary_markdown(report, rows, "farthest", 0)
    assert "No verdicts" not in md and ", yes |" in md and "`scores` " in md and "ahead of farthest" in md


def test_benchmark_md_says_what_not_reached_counts_as_and_its_units():
    from nbvtrain.evaluation.benchmark_report import summary_markdown

    report, rows = _synthetic(2)
    md = summary_markdown(report, rows, "farthest", 0)
    assert md.startswith("# Benchmark: protocol t, 2 objects, 1 start each")  # not "1 starts"
    assert "counts as the budget plus one (7 for these 6 scans)" in md
    farthest = next(line for line in md.splitlines() if line.startswith("| farthest |"))
    assert "6.00 [5.00, 7.00], 1/2 n.r." in farthest and "7.00 [7.00, 7.00], 2/2 n.r." in farthest
    assert "Chamfer (x1e-3 r^2) the Chamfer distance" in md and "in thousandths of r squared" in md


def test_benchmark_tells_meshes_of_one_file_name_apart_and_starts_counts_every_start(small_protocol, tmp_path):
    corpus = tmp_path / "corpus"
    for shape, model in (("mug", "02/aa/models"), ("ring", "02/bb/models")):
        (corpus / model).mkdir(parents=True)
        BUILTIN_SHAPES[shape]().export(corpus / model / "model_normalized.obj")
    assert main(["benchmark", "--protocol", str(small_protocol), "--meshes", str(corpus), "--planners", "farthest",
                 "--starts", "1", "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    rows = list(csv.DictReader(open(tmp_path / "out" / "runs.csv")))
    assert {row["mesh"] for row in rows} == {"02/aa/models/model_normalized.obj", "02/bb/models/model_normalized.obj"}
    assert {row["start"] for row in rows} == {"0"}  # --starts 1: one start, the front one not added
    assert "2 objects, 1 start each" in (tmp_path / "out" / "benchmark.md").read_text()
