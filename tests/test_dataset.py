"""nbvtrain.networks.dataset: the same samples as nbvtrain fit's loader through a plain DataLoader with
worker processes, in memory or lazily, on shards or a published version; the view state
derived from run/step/last_view is what a real reconstruction scanned."""

import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import about
from torch.utils.data import DataLoader

from nbvdata.cli import main as nbvdata_main
from nbvdata.core.config import SimConfig, load_config
from nbvdata.datasets.publish import publish
from nbvdata.schema.manifest import open_verified
from nbvdata.schema.shards import Shard, ShardError
from nbvdata.simulation.episode import Reconstruction, ViewCache, run_reconstruction
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.shapes import builtin_object
from nbvtrain.networks.dataset import NBVDataset, view_state
from nbvtrain.networks.train import _batch
from nbvtrain.networks.training_data import load_shards, published_split, to_grids

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "configs" / "smoke.yaml"


@pytest.fixture(scope="module")
def shards(tmp_path_factory) -> Path:
    """Smoke shards, two runs to a shard, so runs and meshes span several files."""
    out = tmp_path_factory.mktemp("smoke") / "shards"
    assert nbvdata_main(["generate", "--config", str(SMOKE), "--out", str(out), "--set",
                         "generate.runs_per_shard=2", "--workers", "1", "--no-progress"]) == 0
    return out


def _fit_samples(paths, indices, memory_limit_gb=8.0) -> tuple[torch.Tensor, np.ndarray]:
    """Grids and targets of ``indices`` as nbvtrain fit's loader makes them (no augmentation)."""
    data = load_shards(paths, memory_limit_gb)
    try:
        codes, targets, _, _ = _batch(data, np.asarray(indices), np.zeros(len(indices), dtype=np.int64))
        return to_grids(codes, torch.from_numpy(data.palette)), targets
    finally:
        data.close()


def _load_all(dataset, workers: int = 2, batch_size: int = 5) -> dict[str, torch.Tensor]:
    batches = list(DataLoader(dataset, batch_size=batch_size, num_workers=workers, shuffle=False))
    return {key: torch.cat([batch[key] for batch in batches]) for key in batches[0]}


@pytest.mark.parametrize("memory_limit_gb", [8.0, 0.0], ids=["in memory", "lazy"])
def test_two_workers_yield_the_samples_of_fits_loader(shards, memory_limit_gb):
    dataset = NBVDataset(shards, scores=True, view_state=True, memory_limit_gb=memory_limit_gb)
    paths = sorted(shards.glob("*.h5"))
    grids, targets = _fit_samples(paths, np.arange(len(dataset)))
    loaded = _load_all(dataset)
    assert loaded["grid"].shape == (len(dataset), 1, 32, 32, 32) and loaded["grid"].dtype == torch.float32
    assert torch.equal(loaded["grid"], grids) and np.array_equal(loaded["target"].numpy(), targets)
    assert loaded["index"].tolist() == list(range(len(dataset)))
    gains = np.concatenate([Shard(p)["gains"] for p in paths])
    overlaps = np.concatenate([Shard(p)["overlaps"] for p in paths])
    assert np.array_equal(loaded["gains"].numpy(), gains) and np.array_equal(loaded["overlaps"].numpy(), overlaps)
    assert loaded["taken"].dtype == torch.bool and loaded["taken"].shape == gains.shape
    # Shuffled, as a training loop would draw them: each index still brings its own sample.
    for batch in DataLoader(dataset, batch_size=7, num_workers=2, shuffle=True,
                            generator=torch.Generator().manual_seed(0)):
        expected, expected_targets = _fit_samples(paths, batch["index"].numpy(), memory_limit_gb)
        assert torch.equal(batch["grid"], expected) and np.array_equal(batch["target"].numpy(), expected_targets)
    clone = pickle.loads(pickle.dumps(dataset))  # what a spawned worker gets: no open file handles
    assert torch.equal(clone[3]["grid"], dataset[3]["grid"])
    dataset.close()


def test_a_published_version_gives_the_parts_fit_trains_and_validates_on(shards, tmp_path):
    manifest = publish(shards, "smoke", "1.0.0", tmp_path / "manifests", about=about()).path
    published = open_verified(manifest)
    for split in ("random", "mesh"):
        train, val, _ = published_split(published, split)
        for part, indices in (("train", train), ("val", val)):
            dataset = NBVDataset(manifest, part=part, split=split)
            assert np.array_equal(dataset.indices, indices)
            grids, targets = _fit_samples(published.shard_paths, indices)
            loaded = _load_all(dataset)
            assert torch.equal(loaded["grid"], grids) and np.array_equal(loaded["target"].numpy(), targets)
    test = NBVDataset(manifest, part="test", split="mesh")
    assert len(test) == len(published.split("mesh")["test"]) > 0
    with pytest.raises(ShardError, match="needs a published manifest"):
        NBVDataset(shards, part="train")


def test_the_view_state_in_shards_is_the_start_view_and_the_labelled_views_before(shards):
    """Independent of last_view: a run starts at its step-1 state's view and then scans each
    state's NBV (nbv_index) in turn."""
    dataset = NBVDataset(shards, view_state=True)
    paths = sorted(shards.glob("*.h5"))
    columns = {name: np.concatenate([Shard(p)[name] for p in paths]) for name in ("run", "step", "nbv_index",
                                                                                  "last_view", "mesh_id")}
    for i in range(len(dataset)):
        same_run = (columns["mesh_id"] == columns["mesh_id"][i]) & (columns["run"] == columns["run"][i])
        start = np.flatnonzero(same_run & (columns["step"] == 1))[0]
        before = np.flatnonzero(same_run & (columns["step"] < columns["step"][i]))
        expected = {int(columns["last_view"][start])} | set(columns["nbv_index"][before].tolist())
        assert set(np.flatnonzero(dataset.taken[i]).tolist()) == expected
        assert dataset.taken[i].sum() == columns["step"][i]  # no view is scanned twice


def test_the_view_state_is_what_a_real_reconstruction_scanned(monkeypatch):
    """Runs of nbvdata.simulation.episode with every scan logged: at each recorded state the views scanned so
    far are view_state's, whatever order the states come in."""
    config = load_config(SimConfig, SMOKE)
    scene = Scene.build(builtin_object("snowman", config.mesh), config, np.random.default_rng(0), threads=1)
    cache = ViewCache(scene)
    scanned: list[int] = []
    real_scan = Reconstruction.scan
    monkeypatch.setattr(Reconstruction, "scan", lambda self, view: scanned.append(view) or real_scan(self, view))
    runs, steps, last_views, expected = [], [], [], []
    for run, start in enumerate((5, 31, 47)):
        scanned.clear()
        record = run_reconstruction(scene, start, np.random.default_rng(run), cache)
        assert len(record) >= 3
        for state in range(len(record)):
            runs.append(run)
            steps.append(state + 1)
            last_views.append(record.last_view[state])
            expected.append(sorted(scanned[:state + 1]))  # state k is recorded after k + 1 scans
    order = np.random.default_rng(0).permutation(len(runs))
    taken = view_state(np.array(runs)[order], np.array(steps)[order], np.array(last_views)[order], len(scene.views))
    assert [np.flatnonzero(row).tolist() for row in taken] == [expected[i] for i in order]


def test_a_run_missing_a_state_has_no_view_state():
    with pytest.raises(ValueError, match=r"run 4 has states at steps \[1, 3\], not 1..2"):
        view_state(np.array([4, 4]), np.array([1, 3]), np.array([0, 1]), 10)
    with pytest.raises(ValueError, match="outside 0..9"):
        view_state(np.array([0]), np.array([1]), np.array([10]), 10)
    with pytest.raises(ValueError, match="a pose that is no candidate view"):  # a regression policy's rollout
        view_state(np.array([0, 0]), np.array([1, 2]), np.array([3, -1]), 10)


def test_the_docs_example_trains(shards, tmp_path, monkeypatch):
    """The 10 lines of docs/training.md, on a published smoke version in place of builtin-shapes 1.3.0."""
    page = (ROOT / "docs" / "training.md").read_text()
    example = page.split("## The dataset in your own training code", 1)[1].split("```python\n", 1)[1]
    example = example.split("```", 1)[0]
    assert len(example.strip().splitlines()) <= 11
    manifest = publish(shards, "builtin-shapes", "1.3.0", tmp_path / "manifests", about=about()).path
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(example, "docs/training.md", "exec"), namespace)
    assert manifest.exists() and np.isfinite(namespace["loss"].item())
    assert len(namespace["train"]) == len(open_verified(manifest).split("random")["train"])


@pytest.mark.parametrize("memory_limit_gb", [8.0, 0.0], ids=["in memory", "lazy"])
def test_points_true_yields_each_states_cloud(tmp_path, memory_limit_gb):
    out = tmp_path / "clouds"
    assert nbvdata_main(["generate", "--config", str(SMOKE), "--out", str(out), "--set", "state.points=32", "--set",
                         "episode.runs_per_mesh=1", "--workers", "1", "--no-progress"]) == 0
    dataset = NBVDataset(out, points=True, memory_limit_gb=memory_limit_gb)
    loaded = _load_all(dataset)
    paths = sorted(out.glob("*.h5"))
    points = np.concatenate([Shard(p)["points"] for p in paths])
    counts = np.concatenate([Shard(p)["points_count"] for p in paths])
    assert loaded["points"].dtype == torch.float32 and np.array_equal(loaded["points"].numpy(), points)
    assert np.array_equal(loaded["points_count"].numpy(), counts)
    clone = pickle.loads(pickle.dumps(dataset))
    assert torch.equal(clone[2]["points"], dataset[2]["points"]) and torch.equal(clone[2]["grid"], dataset[2]["grid"])
    dataset.close()
    with pytest.raises(ShardError, match="holds no point clouds.*state.points=1024"):
        NBVDataset(_grid_only(tmp_path), points=True)


def _grid_only(tmp_path: Path) -> Path:
    out = tmp_path / "grids"
    assert nbvdata_main(["generate", "--config", str(SMOKE), "--out", str(out), "--set", "episode.runs_per_mesh=1",
                         "--workers", "1", "--no-progress"]) == 0
    return out
