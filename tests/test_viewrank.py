"""The ranker of candidate views (nbvtrain.ranking.viewrank, rankdata, rankfit): fitted on a tiny scene,
its files round-trip exactly and load without pickle, foreign files are one line, the rows do
not depend on the workers, its planner never repeats a view on any view set; the hand-crafted
metrics as planners; LightGBM found without a system OpenMP runtime."""

from __future__ import annotations

import ctypes
import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from nbvdata.cli import main as nbvdata_main
from nbvdata.core.config import SimConfig, load_config
from nbvdata.core.views import view_sphere
from nbvdata.simulation.episode import Reconstruction
from nbvdata.simulation.viewfeatures import BASE, FEATURES, METRICS
from nbvtrain.cli import main as nbvtrain_main
from nbvtrain.networks.checkpoint import CheckpointError
from nbvtrain.planners import PLANNERS, MetricPlanner, Observation, OraclePlanner, RankerPlanner, build_planners
from nbvtrain.ranking.rankdata import RankingData, shard_rows
from nbvtrain.ranking.rankfit import part_rows, sources_parts
from nbvtrain.ranking.viewrank import RankerConfig, load_ranker

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "configs" / "smoke.yaml"
FAST = ["--rays", "4x3", "--sample", "8", "--workers", "1", "--no-progress"]


@pytest.fixture(scope="module")
def shards(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("rank") / "shards"
    assert nbvdata_main(["generate", "--config", str(SMOKE), "--out", str(out), "--runs-per-mesh", "4",
                         "--explore", "0.3", "--no-progress"]) == 0
    return out


@pytest.fixture(scope="module")
def rankers(shards, tmp_path_factory) -> dict[str, Path]:
    runs = tmp_path_factory.mktemp("runs")
    files = {}
    for kind, extra in (("viewrank-gbm", ["--trees", "20"]), ("viewrank-mlp", ["--epochs", "3"])):
        out = runs / kind
        assert nbvtrain_main(["fit", str(shards), "--model", kind, "--out", str(out), "--feature-cache",
                              str(runs / "cache"), *FAST, *extra]) == 0
        files[kind] = out / ("viewrank.json" if kind == "viewrank-gbm" else "viewrank.pt")
    return files


def test_fit_writes_the_model_its_metrics_and_settings(rankers):
    for kind, path in rankers.items():
        metrics = json.loads((path.parent / "metrics.json").read_text())
        assert metrics["model"] == kind and 0 <= metrics["val_gain_ratio"] <= 1
        assert set(metrics["baselines"]) >= set(FEATURES) | {"random", "farthest (its own choice)"}
        assert (path.parent / "config.yaml").is_file() and (path.parent / "history.csv").is_file()
        assert load_ranker(path).kind == kind


def test_a_ranker_file_round_trips_exactly(rankers, tmp_path):
    rng = np.random.default_rng(0)
    features = rng.random((50, len(FEATURES))).astype(np.float32)
    for path in rankers.values():
        ranker = load_ranker(path)
        copy = tmp_path / path.name
        ranker.save(copy)
        rows = features[:, ranker.columns]
        assert np.array_equal(load_ranker(copy).scores(rows), ranker.scores(rows))
        if ranker.booster is not None:  # its compiled trees score as LightGBM does, bit for bit
            assert np.array_equal(ranker.scores(rows), ranker.booster.predict(rows, num_threads=1, raw_score=True))


def test_the_mlp_file_loads_with_weights_only(rankers):
    state = torch.load(rankers["viewrank-mlp"], weights_only=True)
    assert state["format"] == "nbvtrain-viewrank" and state["features"] == list(BASE)  # the default columns


@pytest.mark.parametrize("content, message", [
    (b"hello", "not a ranker file (not JSON"),
    (b'{"format": "something else"}', "not a ranker file (no format"),
    (b'{"format": "nbvtrain-viewrank", "format_version": 9, "kind": "viewrank-gbm"}', "format 9"),
    (b'{"format": "nbvtrain-viewrank", "format_version": 1, "kind": "viewrank-gbm", "features": [], "rays": [4, 3], '
     b'"scene": {}, "training": {}, "lightgbm": "tree\\nnonsense"}', "LightGBM model does not load"),
])
def test_a_bad_ranker_file_is_one_line(tmp_path, content, message):
    path = tmp_path / "model.json"
    path.write_bytes(content)
    with pytest.raises(CheckpointError, match=re.escape(message)) as caught:
        load_ranker(path)
    assert "\n" not in str(caught.value) and "nbvtrain fit --model viewrank" in str(caught.value)


def test_a_foreign_torch_file_is_refused_without_running_it(tmp_path):
    path = tmp_path / "viewrank.pt"
    torch.save({"weights": torch.zeros(3)}, path)
    with pytest.raises(CheckpointError, match="not a ranker file"):
        load_ranker(path)
    evil = tmp_path / "viewrank-evil.pt"
    torch.save({"format": "nbvtrain-viewrank", "payload": Path("x")}, evil)  # a pickled object
    with pytest.raises(CheckpointError, match="not a ranker file"):
        load_ranker(evil)


def test_a_bad_ranker_for_evaluate_exits_2_in_one_line(shards, tmp_path, capsys):
    import trimesh

    bad = tmp_path / "viewrank.json"
    bad.write_text("{}")
    (tmp_path / "meshes").mkdir()
    trimesh.creation.box().export(tmp_path / "meshes" / "box.stl")
    code = nbvtrain_main(["evaluate", "--meshes", str(tmp_path / "meshes"), "--planners", "viewrank", "--ranker",
                          str(bad), "--config", str(SMOKE), "--out", str(tmp_path / "e")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "not a ranker file" in err[0]


def test_rows_do_not_depend_on_the_workers(shards, tmp_path):
    train, val, _ = sources_parts([shards])
    config = RankerConfig(rays=(4, 3), sample=8)
    one = part_rows(train, config, 8, None, 1, False, "train")
    two = part_rows(train, config, 8, tmp_path / "cache", 2, False, "train")
    again = part_rows(train, config, 8, tmp_path / "cache", 1, False, "train")  # read back from the cache
    for name in RankingData.__dataclass_fields__:
        assert np.array_equal(getattr(one, name), getattr(two, name)), name
        assert np.array_equal(getattr(one, name), getattr(again, name)), name
    assert set(np.unique(np.concatenate([p.states for p in train]))).isdisjoint(set()) and val


def test_rows_sample_the_best_views_and_label_valid_gains(shards):
    path = sorted(shards.glob("*.h5"))[0]
    full = shard_rows(path, (4, 3), 0)
    few = shard_rows(path, (4, 3), 8)
    assert (few.sizes <= 8).all() and (full.sizes >= few.sizes).all()
    assert np.allclose(few.best, full.best)  # the best is over every unscanned view, sampled or not
    starts = few.starts
    for s in range(len(few)):
        rows = slice(starts[s], starts[s] + few.sizes[s])
        assert few.gains[rows].max() == pytest.approx(few.best[s])  # the best view is always kept
    assert (full.gains <= full.other + 1e-9).all()  # a valid gain is the gain or 0
    everything = full.labelled("all")
    assert np.array_equal(everything.gains, full.other) and everything.labelled("valid").gains is not None


def test_the_gain_ratio_of_the_labels_themselves_is_one(shards):
    data = shard_rows(sorted(shards.glob("*.h5"))[0], (4, 3), 0)
    assert data.gain_ratio(data.gains) == pytest.approx(1.0)
    assert data.gain_ratio(-data.gains) < 1.0


@pytest.mark.parametrize("layout, count", [("hemisphere", 60), ("pc-nbv-33", 33), ("tammes-128", 128)])
def test_the_ranker_plans_on_any_view_set_and_never_repeats(rankers, layout, count):
    config = load_config(SimConfig, SMOKE, [f"views.layout={layout}", f"views.count={count}"])
    views = view_sphere(config.views)
    planner = RankerPlanner(rankers["viewrank-gbm"], views, config)
    grid = np.full((32, 32, 32), 0.5, dtype=np.float32)
    grid[12:20, 12:20, 12:20] = 0.7
    poses = []
    for _ in range(min(count, 12)):
        pose = planner.next_pose(Observation(grid, tuple(poses)))
        assert not any(np.array_equal(pose.position, p.position) for p in poses)
        poses.append(pose)


def test_a_ranker_of_another_grid_is_refused(rankers):
    config = load_config(SimConfig, SMOKE, ["grid.size=16"])
    from nbvdata.core.config import ConfigError

    with pytest.raises(ConfigError, match="trained on 32\\^3 grids"):
        RankerPlanner(rankers["viewrank-gbm"], view_sphere(config.views), config)


def test_every_metric_is_a_registered_planner_that_takes_its_best_unscanned_view():
    config = load_config(SimConfig, SMOKE)
    views = view_sphere(config.views)
    grid = np.full((32, 32, 32), 0.5, dtype=np.float32)
    grid[8:24, 8:24, 4:20] = 0.4
    grid[12:20, 12:20, 4:14] = 0.7
    poses = (views[5],)
    for name in METRICS:
        assert name in PLANNERS
        (planner,), _ = build_planners([name], config, views, {})
        assert isinstance(planner, MetricPlanner)
        values = planner.values(Observation(grid, poses))
        values[5] = -np.inf
        pose = planner.next_pose(Observation(grid, poses))
        assert np.array_equal(pose.position, views.positions[int(np.argmax(values))])


def test_the_oracle_takes_farthest_s_view_when_nothing_is_left(tmp_path):
    from nbvdata.simulation.scene import Scene
    from nbvdata.simulation.shapes import builtin_object

    config = load_config(SimConfig, SMOKE)
    scene = Scene.build(builtin_object("pill", config.mesh), config, np.random.default_rng(0))
    state = Reconstruction(scene, None, np.random.default_rng(0))
    for view in range(len(scene.views)):
        state.scan(view)
    observation = Observation(state.grid.probabilities(), (scene.views[0], scene.views[7]))
    assert not (scene.oracle.score(state.covered).new > 0).any()
    pose = OraclePlanner(scene.views, config.oracle.min_overlap).next_pose(observation, state)
    units = scene.views.unit_positions
    from nbvdata.core.views import farthest_view

    assert np.array_equal(pose.position, scene.views.positions[farthest_view(units, observation.positions)])
    assert farthest_view(units, observation.positions) not in (0, 7)


def test_lightgbm_loads_torch_s_openmp_when_the_system_has_none(monkeypatch):
    import nbvtrain.ranking._lightgbm as module

    loaded = []
    real = ctypes.CDLL

    def cdll(name, mode=0):
        if name == "libgomp.so.1":
            raise OSError("libgomp.so.1: cannot open shared object file")
        loaded.append(str(name))
        return real(name, mode)

    monkeypatch.setattr(ctypes, "CDLL", cdll)
    module._preload_libgomp()
    assert loaded and loaded[0].endswith("torch/lib/libgomp.so.1")


def test_the_ranker_plays_the_environment_and_never_repeats(rankers):
    from nbvdata.env import ReconstructEnv
    from nbvtrain.ranking.viewrank import env_choice

    env = ReconstructEnv(config=SMOKE)
    choose = env_choice(load_ranker(rankers["viewrank-gbm"]), env.views, env.config)
    observation, info = env.reset(seed=0)
    chosen = []
    for _ in range(3):
        view = choose(observation, info["action_mask"])
        assert info["action_mask"][view] and view not in chosen
        chosen.append(view)
        observation, _, terminated, truncated, info = env.step(view)
        if terminated or truncated:
            break


def test_generate_follows_a_ranker_and_labels_every_state(shards, rankers, tmp_path, capsys):
    """DAgger rounds of a ranker (issue 63): runs move where the ranker would (the viewrank
    provider), every state still labelled by the exhaustive search; a ranker file given to the
    networks' provider says which provider takes it."""
    from nbvdata.schema.shards import Shard, view_state

    ranker = rankers["viewrank-gbm"]
    out = tmp_path / "round"
    assert nbvdata_main(["generate", "--config", str(SMOKE), "--out", str(out), "--runs-per-mesh", "2", "--policy",
                         str(ranker), "--policy-provider", "viewrank", "--no-progress"]) == 0
    planner = RankerPlanner(ranker, view_sphere(load_config(SimConfig, SMOKE, []).views), load_config(SimConfig, SMOKE, []))
    followed = 0
    for path in sorted(out.glob("*.h5")):
        with Shard(path) as shard:
            assert json.loads(shard.file.attrs["policy"])["provider"] == "viewrank"
            moves, nexts, last = shard["move"], shard["next_view"], shard["last_view"]
            taken = view_state(shard["run"], shard["step"], last, len(shard["view_positions"]))
            grids = shard.grids()
            for i in np.flatnonzero(moves == 2):  # the policy's moves: the ranker's own choice at that state
                observation = Observation(grids[i], tuple(planner.views[v] for v in np.flatnonzero(taken[i])))
                assert nexts[i] == planner.next_view(observation)
                followed += 1
            assert (shard["nbv_index"] >= 0).all()
    assert followed > 0
    code = nbvdata_main(["generate", "--config", str(SMOKE), "--out", str(tmp_path / "other"), "--policy", str(ranker),
                         "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "add --policy-provider viewrank" in err[0]


@pytest.fixture(scope="module")
def surface_shards(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("surface") / "shards"
    assert nbvdata_main(["generate", "--config", str(SMOKE), "--out", str(out), "--runs-per-mesh", "3",
                         "--explore", "0.3", "--set", "state.surface=true", "--no-progress"]) == 0
    return out


def test_a_surface_prior_and_a_ranker_that_carries_it(surface_shards, tmp_path, capsys):
    """surface-gbm learns P(surface) of unknown voxels from the shards' surface voxels; a ranker of
    the surface group reads its expected surface and carries the prior in its own file."""
    from nbvdata.schema.shards import Shard, view_state
    from nbvdata.simulation.viewfeatures import shadow_weights
    from nbvtrain.ranking.rankdata import bundle_for
    from nbvtrain.ranking.surfaceprior import load_surface_prior

    prior_run, ranker_run = tmp_path / "surface", tmp_path / "ranker"
    assert nbvtrain_main(["fit", str(surface_shards), "--model", "surface-gbm", "--trees", "20", "--workers", "1",
                          "--out", str(prior_run)]) == 0
    metrics = json.loads((prior_run / "metrics.json").read_text())
    assert 0 <= metrics["val"]["all"]["recall"] <= 1 and 0 < metrics["far_rate"] < 1
    prior = load_surface_prior(prior_run / "surface.json")
    config = load_config(SimConfig, SMOKE, [])
    path = sorted(surface_shards.glob("*.h5"))[0]
    with Shard(path) as shard:
        grid, positions = shard.grids(1), shard["view_positions"]
        taken = view_state(shard["run"], shard["step"], shard["last_view"], len(positions))[1]
    views = view_sphere(config.views)
    shadow = shadow_weights(grid, positions[taken], bundle_for(views, config))
    probabilities = prior.probabilities(grid, shadow)
    assert ((probabilities >= 0) & (probabilities <= 1)).all() and (probabilities[grid != 0.5] == 0).all()
    assert nbvtrain_main(["fit", str(surface_shards), "--model", "viewrank-gbm", "--features", "base,surface",
                          "--out", str(tmp_path / "bad"), *FAST, "--trees", "5"]) == 2
    assert "--surface-prior FILE" in capsys.readouterr().err
    assert nbvtrain_main(["fit", str(surface_shards), "--model", "viewrank-gbm", "--features", "base,surface",
                          "--surface-prior", str(prior_run / "surface.json"), "--out", str(ranker_run),
                          "--feature-cache", str(tmp_path / "cache"), *FAST, "--trees", "5"]) == 0
    ranker = load_ranker(ranker_run / "viewrank.json")
    assert ranker.prior is not None and "expected_surface" in ranker.features
    scores = ranker.view_scores(grid, positions[taken], views, config)
    assert scores.shape == (len(views),) and np.isfinite(scores).all()
    # the expected-surface planner: the unscanned view whose rays expect the most new surface
    from nbvdata.simulation.viewfeatures import METRIC_BUNDLE, view_features
    from nbvtrain.planners import SurfacePlanner

    (planner,), _ = build_planners(["expected-surface"], config, views, {"surface": prior_run / "surface.json"})
    assert isinstance(planner, SurfacePlanner)
    observation = Observation(grid, tuple(views[i] for i in np.flatnonzero(taken)))
    bundle = bundle_for(views, config, METRIC_BUNDLE)
    shadow = shadow_weights(grid, observation.positions, bundle)
    expected = view_features(grid, observation.positions, bundle, prior.probabilities(grid, shadow), shadow)
    values = planner.values(observation)
    assert np.array_equal(values, expected[:, FEATURES.index("expected_surface")]) and values.max() > 0
    values[taken] = -np.inf
    assert np.array_equal(planner.next_pose(observation).position, views.positions[int(np.argmax(values))])
    _, skipped = build_planners(["expected-surface"], config, views, {})
    assert "--surface-prior runs/surface-gbm/surface.json" in str(skipped)
    head = json.loads((ranker_run / "viewrank.json").read_text())
    carried = json.loads(head["surface_prior"])
    carried["lightgbm"] = carried["lightgbm"].replace("Tree=1", "Tree=9", 1)
    (tmp_path / "damaged.json").write_text(json.dumps(head | {"surface_prior": json.dumps(carried)}))
    with pytest.raises(CheckpointError, match="damaged"):
        load_ranker(tmp_path / "damaged.json")


def test_mesh_weights_weigh_the_states_of_the_meshes_they_name(shards, tmp_path, capsys):
    """--mesh-weight PATTERN=W: the training states of meshes whose file name matches weigh W (the
    first pattern that matches), others 1; a weight that is no positive number is refused."""
    from nbvtrain.ranking.rankfit import state_weights

    train, _, _ = sources_parts([shards])
    rows = part_rows(train, RankerConfig(rays=(4, 3), sample=8), 8, None, 1, False, "train")
    weights = state_weights(rows, train, (("builtin:mug*", 3.0), ("*", 0.5)))
    from nbvdata.schema.shards import Shard

    mug = set()
    for part in train:
        with Shard(part.path) as shard:
            mug |= {mesh["id"] for mesh in shard.info.meshes if mesh["source"].startswith("builtin:mug")}
    assert set(weights[np.isin(rows.mesh_ids, list(mug))]) <= {3.0} and set(weights) <= {3.0, 0.5}
    assert nbvtrain_main(["fit", str(shards), "--model", "viewrank-gbm", "--mesh-weight", "builtin:mug=3",
                          "--out", str(tmp_path / "weighted"), *FAST, "--trees", "5"]) == 0
    assert load_ranker(tmp_path / "weighted" / "viewrank.json").training["mesh_weights"] == [["builtin:mug", 3.0]]
    with pytest.raises(SystemExit):
        nbvtrain_main(["fit", str(shards), "--model", "viewrank-gbm", "--mesh-weight", "random_*=-1"])
    assert "W a positive number" in capsys.readouterr().err
