"""The selection protocol: ``nbvtrain evaluate --manifest M --part P --meshes ROOT`` evaluates
exactly the meshes of that part of a published version's mesh split, found by the file names and
sha256 the manifest records, and refuses a changed or missing file, an unknown or empty part, in
one line (exit 2); config.yaml records which version and part chose what. A DAgger round
(``nbvdata generate --manifest M --part train --policy CKPT``) joins the version's training part
(``nbvtrain fit M --add-train DIR --init CKPT``) and never its validation objects."""

from __future__ import annotations

import csv
import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
import yaml
from conftest import MESHES, about, need

from nbvdata.cli import main as nbvdata_main
from nbvdata.core.config import SimConfig, load_config
from nbvdata.datasets.generate import generate
from nbvdata.datasets.publish import publish
from nbvdata.schema.manifest import ManifestError, load_manifest
from nbvdata.schema.shards import Shard, view_state
from nbvdata.simulation.shapes import BUILTIN_SHAPES
from nbvdata.simulation.sources import find_part_meshes, mesh_sources
from nbvtrain.cli import main
from nbvtrain.networks.training_data import nearest_views

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "configs" / "smoke.yaml"
NAMES = ("mug", "ring", "pill", "snowman", "step_block")
FAST = ["--model", "nbvnet-3-3", "--batch-size", "16", "--threads", "1", "--no-progress"]


@pytest.fixture(scope="module")
def version(tmp_path_factory) -> tuple[Path, Path]:
    """Five mesh files, one run each in a tiny scene, published as sel 1.0.0 with a train, val
    and test part: (the manifest, the folder of the meshes, nested one level down)."""
    base = tmp_path_factory.mktemp("version")
    folder = base / "meshes" / "objects"
    folder.mkdir(parents=True)
    for name in NAMES:
        BUILTIN_SHAPES[name]().export(folder / f"{name}.obj")
    sources, failures = mesh_sources(folder)
    config = load_config(SimConfig, SMOKE, ["episode.runs_per_mesh=1", "episode.max_scans=2", "generate.workers=1"])
    assert not failures and not generate(sources, base / "shards", config).failures
    result = publish(base / "shards", "sel", "1.0.0", base / "manifests", val_fraction=0.2, test_fraction=0.2, about=about())
    return result.path, base / "meshes"


def _copy(meshes: Path, where: Path) -> Path:
    return Path(shutil.copytree(meshes, where))


def _part_ids(manifest: Path, part: str) -> list[str]:
    return json.loads(manifest.read_text())["splits"]["mesh"][part]["meshes"]


def test_each_part_finds_exactly_its_meshes_by_name_and_sha256(version, tmp_path):
    manifest, meshes = version
    root = _copy(meshes, tmp_path / "root")
    # a decoy: a file of the same name elsewhere under the root, with other content, sorted first
    decoy = root / "a-old" / "mug.obj"
    decoy.parent.mkdir()
    trimesh.creation.box().export(decoy)
    published = load_manifest(manifest)
    seen = []
    for part in ("train", "val", "test"):
        found = find_part_meshes(published, part, root)
        assert [mesh.mesh_id for mesh in found] == _part_ids(manifest, part)
        for mesh in found:
            assert mesh.path.name == mesh.source and mesh.path != decoy
            assert hashlib.sha256(mesh.path.read_bytes()).hexdigest() == mesh.mesh_id
        seen += [mesh.source for mesh in found]
    assert sorted(seen) == sorted(f"{name}.obj" for name in NAMES)  # the parts cover the version, once each


def test_evaluate_runs_the_val_meshes_and_records_the_version(version, tmp_path, capsys):
    manifest, meshes = version
    out = tmp_path / "eval"
    assert main(["evaluate", "--manifest", str(manifest), "--part", "val", "--meshes", str(meshes),
                 "--planners", "random", "--scans", "2", "--config", str(SMOKE), "--out", str(out),
                 "--no-progress"]) == 0
    (val,) = find_part_meshes(load_manifest(manifest), "val", meshes)
    with open(out / "coverage.csv") as handle:
        assert {row["mesh"] for row in csv.DictReader(handle)} == {Path(val.source).stem}
    record = yaml.safe_load((out / "config.yaml").read_text())["evaluate"]["manifest"]
    assert record == {"name": "sel", "version": "1.0.0", "sha256": hashlib.sha256(manifest.read_bytes()).hexdigest(),
                      "path": str(manifest.resolve()), "part": "val", "meshes": 1}


def test_a_changed_mesh_is_refused_naming_it(version, tmp_path, capsys):
    manifest, meshes = version
    root = _copy(meshes, tmp_path / "root")
    (val,) = find_part_meshes(load_manifest(manifest), "val", root)
    with open(val.path, "a") as handle:
        handle.write("# one more line: another file, another sha256\n")
    assert main(["evaluate", "--manifest", str(manifest), "--part", "val", "--meshes", str(root),
                 "--planners", "random", "--out", str(tmp_path / "eval")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and str(val.path) in err and "sha256 differs" in err
    assert not (tmp_path / "eval").exists()


def test_a_missing_mesh_is_refused_naming_it(version, tmp_path, capsys):
    manifest, meshes = version
    root = _copy(meshes, tmp_path / "root")
    (test,) = find_part_meshes(load_manifest(manifest), "test", root)
    test.path.unlink()
    assert main(["evaluate", "--manifest", str(manifest), "--part", "test", "--meshes", str(root),
                 "--planners", "random", "--out", str(tmp_path / "eval")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and test.source in err and "not found" in err
    with pytest.raises(ManifestError, match="pass --meshes ROOT"):  # files, but no folder to find them in
        find_part_meshes(load_manifest(manifest), "val", None)


@pytest.mark.parametrize("flags, message", [
    (["--part", "validation"], "choose train, val or test"),
    ([], "--manifest needs --part"),
])
def test_an_unknown_or_missing_part_is_refused(version, tmp_path, capsys, flags, message):
    manifest, meshes = version
    assert main(["evaluate", "--manifest", str(manifest), *flags, "--meshes", str(meshes), "--planners", "random",
                 "--out", str(tmp_path / "eval")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and message in err


def test_an_empty_part_and_a_part_without_a_manifest_are_refused(version, tmp_path, capsys):
    manifest, meshes = version
    root = manifest.parent.parent
    empty = publish(root / "shards", "sel", "1.1.0", tmp_path / "manifests", test_fraction=0, about=about()).path
    assert main(["evaluate", "--manifest", str(empty), "--part", "test", "--meshes", str(meshes),
                 "--out", str(tmp_path / "eval")]) == 2
    assert "holds no meshes (published with --test-fraction 0" in capsys.readouterr().err
    assert main(["evaluate", "--part", "val", "--meshes", str(meshes), "--out", str(tmp_path / "eval")]) == 2
    assert "--part val needs --manifest" in capsys.readouterr().err


def test_built_in_shapes_of_a_version_need_no_files():
    """builtin-shapes 1.2.0 (published): its parts are built-in shapes, checked by their mesh ids."""
    published = load_manifest(ROOT / "manifests" / "builtin-shapes-1.2.0.json")
    for part in ("train", "val", "test"):
        found = find_part_meshes(published, part, None)
        assert [mesh.mesh_id for mesh in found] == published.content["splits"]["mesh"][part]["meshes"]
        assert all(mesh.path is None and mesh.source.startswith("builtin:") for mesh in found)


def test_the_released_versions_val_part_is_found_in_the_shared_meshes():
    """train-meshes 1.1.0's val meshes: shared train meshes and procedural objects of extra/."""
    need(MESHES / "extra")
    found = find_part_meshes(load_manifest(ROOT / "manifests" / "train-meshes-1.1.0.json"), "val", MESHES)
    folders = {mesh.path.parent.name for mesh in found}
    assert len(found) == 110 and folders == {"train", "pybullet_random_urdfs"}
    assert sum(mesh.path.parent.name == "pybullet_random_urdfs" for mesh in found) == 85


def _evaluation(folder: Path, finals: dict[str, float], checkpoint: str) -> Path:
    """A fake evaluate folder: one start per mesh, 2 scans, the given final coverage per mesh."""
    folder.mkdir(parents=True)
    lines = ["mesh,planner,start,start_view,scan,coverage,observable_coverage,seconds,x,y,z,overlap,valid_views"]
    for mesh, final in finals.items():
        lines += [f"{mesh},scores,0,0,1,0.1,0.1,0,0,0,0,,", f"{mesh},scores,0,0,2,{final},{final},0.002,0,0,0,0.5,3"]
    (folder / "coverage.csv").write_text("\n".join(lines) + "\n")
    settings = {"evaluate": {"meshes": None, "manifest": {"name": "v", "version": "1.0.0", "part": "val"},
                             "checkpoints": {"scores": checkpoint}}}
    (folder / "config.yaml").write_text(yaml.safe_dump(settings))
    return folder


def test_the_selection_table_ranks_by_the_shared_meshes_and_says_when_a_run_stopped_improving(tmp_path):
    """recipes/selection_table.py, which the recipe's convergence rule and choices read."""
    import subprocess
    import sys

    script = ROOT / "recipes" / "selection_table.py"
    shared = {2: 0.80, 4: 0.90, 6: 0.85, 8: 0.88}  # epoch -> shared-mesh coverage; procedural falls as shared rises
    folders = [_evaluation(tmp_path / f"net-e{epoch:03d}", {"cup": value, "random_007": 1.5 - value},
                           f"epoch-{epoch}.pt") for epoch, value in shared.items()]

    def run(*args):
        return subprocess.run([sys.executable, str(script), *args, *map(str, folders)], capture_output=True, text=True)

    assert run("--top", "2").stdout.strip() == "epoch-4.pt,epoch-8.pt"
    assert run("--top", "1", "--by", "procedural").stdout.strip() == "epoch-2.pt"
    assert run("--stopped", "2").returncode == 0 and run("--stopped", "3").returncode == 1
    table = run().stdout
    assert "| net-e004 | scores **best** | v 1.0.0 val | 2 | 2 | 75.0 | 90.0 | 60.0 | 2.0 | epoch-4.pt |" in table
    by_scan = run("--by-scan").stdout  # one column per folder's planner, one row per scan
    shared_part = by_scan.split("shared:")[1].split("procedural:")[0]
    assert "| scan | net-e002/scores | net-e004/scores | net-e006/scores | net-e008/scores |" in shared_part
    assert "| 1 | 10.0 | 10.0 | 10.0 | 10.0 |" in shared_part and "| 2 | 80.0 | 90.0 | 85.0 | 88.0 |" in shared_part
    assert "| 2 | 70.0 | 60.0 | 65.0 | 62.0 |" in by_scan.split("procedural:")[1].split("all:")[0]
    assert "| 2 | 75.0 | 75.0 | 75.0 | 75.0 |" in by_scan.split("all:")[1]


def _mesh_ids(folder: Path) -> set[str]:
    ids = set()
    for path in folder.glob("*.h5"):
        with Shard(path) as shard:
            ids |= set(shard["mesh_id"].astype(str).tolist())
    return ids


def _generate_part(manifest: Path, part: str, meshes: Path, out: Path, policy: Path) -> None:
    assert nbvdata_main(["generate", "--manifest", str(manifest), "--part", part, "--meshes", str(meshes),
                         "--policy", str(policy), "--config", str(SMOKE), "--set", "episode.max_scans=2",
                         "--runs-per-mesh", "1", "--workers", "1", "--out", str(out), "--no-progress"]) == 0


def test_a_dagger_round_of_the_training_part_fine_tunes_and_never_touches_validation(version, tmp_path, capsys):
    manifest, meshes = version
    first = tmp_path / "first"
    assert main(["fit", str(manifest), "--split", "mesh", "--epochs", "1", "--out", str(first),
                 "--regression-loss", "near-best", *FAST]) == 0
    plain = json.loads((first / "data.json").read_text())
    # the round: the policy's runs on exactly the training part's meshes
    dagger = tmp_path / "dagger"
    _generate_part(manifest, "train", meshes, dagger, first / "best.pt")
    assert _mesh_ids(dagger) == set(_part_ids(manifest, "train"))
    with Shard(next(dagger.glob("*.h5"))) as shard:
        added_samples = len(shard) * len(_part_ids(manifest, "train"))
        assert (shard["move"][shard["move"] >= 0] == 2).all()  # every move the policy's
    # fine-tuning: every added sample trains, the validation samples are the version's own
    tuned = tmp_path / "tuned"
    assert main(["fit", str(manifest), "--split", "mesh", "--add-train", str(dagger), "--init",
                 str(first / "best.pt"), "--lr", "1e-12", "--epochs", "1", "--out", str(tuned),
                 "--regression-loss", "near-best", *FAST]) == 0  # near-best: the view states of policy poses
    data = json.loads((tuned / "data.json").read_text())
    assert data["val_indices"] == plain["val_indices"] and data["val_samples"] == plain["val_samples"]
    assert data["train_samples"] == plain["train_samples"] + added_samples
    assert len(data["added_train"]) == len(list(dagger.glob("*.h5")))
    init = data["init"]
    assert init["sha256"] == hashlib.sha256((first / "best.pt").read_bytes()).hexdigest() and init["epoch"] == 1
    start = torch.load(first / "best.pt", weights_only=True)["state_dict"]
    after = torch.load(tuned / "last.pt", weights_only=True)["state_dict"]
    assert all(torch.allclose(start[key].float(), after[key].float(), atol=1e-6) for key in start)  # lr 1e-12
    # its release's card names the round, its policy and the whole chain's epochs and time
    assert main(["release", "--regression", str(tuned), "--out", str(tmp_path / "released")]) == 0
    card = (tmp_path / "released" / "MODEL_CARD.md").read_text()
    seconds = sum(torch.load(run / "last.pt", weights_only=True)["history"][0]["seconds"] for run in (first, tuned))
    assert (f"every state labelled exactly): {len(data['added_train'])} shards of `dagger`, rolled by nbvnet-3-3 "
            f"epoch 1 (sha256 {init['sha256'][:12]})." in card)
    assert (f"- Started from (`fit --init`): `best.pt` (epoch 1, sha256 {init['sha256'][:12]}); the chain in all: "
            f"2 epochs in {seconds / 60:.1f} min of wall time." in card)
    assert init["seconds"] == torch.load(first / "best.pt", weights_only=True)["history"][0]["seconds"]
    record = (tuned / "data.json").read_text()  # an older nbvtrain's record (no time), of a file not here
    old = {key: init[key] for key in ("path", "sha256", "epoch")}
    (tuned / "data.json").write_text(json.dumps({**data, "init": {**old, "path": str(tmp_path / "elsewhere.pt")}}))
    assert main(["release", "--regression", str(tuned), "--out", str(tmp_path / "elsewhere")]) == 0
    card = (tmp_path / "elsewhere" / "MODEL_CARD.md").read_text()
    assert "the chain in all: at least 2 epochs (a run of the chain is not on this machine" in card
    (tuned / "data.json").write_text(json.dumps({**data, "init": old}))  # ... of a file still here
    # recipes/regression_answers.py --shards: the policy's own states, its poses as their nearest views
    answers = subprocess.run([sys.executable, str(ROOT / "recipes" / "regression_answers.py"), str(first),
                              str(first / "best.pt"), "--shards", str(dagger), "--samples", "5"],
                             capture_output=True, text=True, check=True).stdout.splitlines()
    assert answers[0].startswith(f"5 states of {dagger}") and answers[3].split()[-3] == "1.000"  # labels: the best
    # resuming reuses the added shards; other ones are refused
    assert main(["fit", "--resume", "--epochs", "2", "--out", str(tuned), "--no-progress"]) == 0
    resumed = json.loads((tuned / "data.json").read_text())
    assert resumed["train_samples"] == data["train_samples"] and resumed["init"] == init  # the record, completed
    (tuned / "data.json").write_text(record)
    capsys.readouterr()
    others = manifest.parent.parent / "shards"
    assert main(["fit", "--resume", "--epochs", "3", "--add-train", str(others), "--out", str(tuned), "--no-progress"]) == 2
    assert "resume without --add-train" in capsys.readouterr().err
    # a round on the validation part would leak into the objects that choose: refused, nothing written
    leak = tmp_path / "leak"
    _generate_part(manifest, "val", meshes, leak, first / "best.pt")
    capsys.readouterr()
    assert main(["fit", str(manifest), "--split", "mesh", "--add-train", str(leak), "--epochs", "1",
                 "--out", str(tmp_path / "no"), *FAST]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "validation or test part" in err and "--part train" in err
    assert not (tmp_path / "no").exists()


def test_a_run_started_from_a_released_file_keeps_its_chain_when_released_over_it(version, tmp_path):
    manifest, _ = version
    first = tmp_path / "first"
    assert main(["fit", str(manifest), "--split", "mesh", "--epochs", "1", "--out", str(first), *FAST]) == 0
    shelf = tmp_path / "released"
    assert main(["release", "--regression", str(first), "--out", str(shelf)]) == 0
    package = shelf / "nbvnet-3-3.pt"  # float16, outside any run folder
    started = hashlib.sha256(package.read_bytes()).hexdigest()
    tuned = tmp_path / "tuned"
    assert main(["fit", str(manifest), "--split", "mesh", "--init", str(package), "--epochs", "1",
                 "--out", str(tuned), *FAST]) == 0
    assert main(["release", "--regression", str(tuned), "--out", str(shelf)]) == 0  # replaces the file it started from
    assert hashlib.sha256(package.read_bytes()).hexdigest() != started
    seconds = [torch.load(run / "last.pt", weights_only=True)["history"][0]["seconds"] for run in (first, tuned)]
    line = (f"- Started from (`fit --init`): `nbvnet-3-3.pt` (epoch 1, sha256 {started[:12]}); the chain in all: "
            f"2 epochs in {sum(seconds) / 60:.1f} min of wall time.")
    assert line in (shelf / "MODEL_CARD.md").read_text()
    # the chain was recorded when each run started: neither the first run nor the file is needed later
    shutil.rmtree(first)
    package.unlink()
    assert main(["release", "--regression", str(tuned), "--out", str(tmp_path / "later")]) == 0
    assert line in (tmp_path / "later" / "MODEL_CARD.md").read_text()
    again = tmp_path / "again"
    assert main(["fit", str(manifest), "--split", "mesh", "--init", str(tuned / "best.pt"), "--epochs", "1",
                 "--out", str(again), *FAST]) == 0
    assert main(["release", "--regression", str(again), "--out", str(tmp_path / "third")]) == 0
    seconds.append(torch.load(again / "last.pt", weights_only=True)["history"][0]["seconds"])
    tuned_sha = hashlib.sha256((tuned / "best.pt").read_bytes()).hexdigest()
    assert (f"`best.pt` (epoch 1, sha256 {tuned_sha[:12]}), which started from `nbvnet-3-3.pt` (epoch 1, sha256 "
            f"{started[:12]}); the chain in all: 3 epochs in {sum(seconds) / 60:.1f} min of wall time." in
            (tmp_path / "third" / "MODEL_CARD.md").read_text())
    # a checkpoint that started from another, whose run is not on this machine: the chain's time is unknown
    (tuned / "data.json").unlink()
    elsewhere = tmp_path / "elsewhere"
    assert main(["fit", str(manifest), "--split", "mesh", "--init", str(tuned / "best.pt"), "--epochs", "1",
                 "--out", str(elsewhere), *FAST]) == 0
    assert json.loads((elsewhere / "data.json").read_text())["init"]["from"] == "unknown"
    assert main(["release", "--regression", str(elsewhere), "--out", str(tmp_path / "fourth")]) == 0
    assert "the chain in all: at least 2 epochs" in (tmp_path / "fourth" / "MODEL_CARD.md").read_text()


@pytest.mark.parametrize("flags, message", [
    (["--add-train", "DAGGER"], "add --split mesh"),                          # the random split mixes objects
    (["--split", "mesh", "--init", "FIRST", "--model", "nbvnet-3-5"], "a nbvnet-3-3 checkpoint"),
    (["--split", "mesh", "--init", "MISSING"], "no such checkpoint file"),
])
def test_dagger_fine_tuning_refuses_what_it_cannot_do_in_one_line(version, tmp_path, capsys, flags, message):
    manifest, meshes = version
    first = tmp_path / "first"
    assert main(["fit", str(manifest), "--split", "mesh", "--epochs", "1", "--out", str(first), *FAST]) == 0
    if "DAGGER" in flags:
        _generate_part(manifest, "train", meshes, tmp_path / "dagger", first / "best.pt")
    where = {"DAGGER": tmp_path / "dagger", "FIRST": first / "best.pt", "MISSING": tmp_path / "none.pt"}
    flags = [str(where.get(flag, flag)) for flag in flags]
    capsys.readouterr()
    assert main(["fit", str(manifest), *FAST, "--epochs", "1", *flags, "--out", str(tmp_path / "no")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and message in err, err
    assert not (tmp_path / "no").exists()


def test_add_train_needs_a_version_and_generate_parts_need_a_manifest(version, tmp_path, capsys):
    manifest, meshes = version
    shards = manifest.parent.parent / "shards"
    assert main(["fit", str(shards), "--add-train", str(shards), "--out", str(tmp_path / "no"), *FAST]) == 2
    assert "--add-train joins the training part of a published version" in capsys.readouterr().err
    assert nbvdata_main(["generate", "--part", "train", "--meshes", str(meshes), "--out", str(tmp_path / "g")]) == 2
    assert "--part train needs --manifest" in capsys.readouterr().err
    assert not (tmp_path / "no").exists() and not (tmp_path / "g").exists()


def test_a_policy_pose_counts_as_the_candidate_view_nearest_to_it():
    views = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [-1.0, 0, 0]]) * 0.4
    run, step = np.array([7, 7, 7, 8]), np.array([1, 2, 3, 1])
    last = np.array([0, -1, -1, 3])
    next_position = np.array([[0.01, 0.5, 0.02], [-0.3, 0.05, 0.9], [9, 9, 9], [0, 0, 0]])  # beside views 1 and 2
    assert nearest_views(run, step, last, next_position, views).tolist() == [0, 1, 2, 3]
    taken = view_state(run, step, nearest_views(run, step, last, next_position, views), 4)
    assert taken.tolist() == [[True, False, False, False], [True, True, False, False], [True, True, True, False],
                              [False, False, False, True]]
    with pytest.raises(ValueError, match="step 2 was reached through a pose"):
        nearest_views(run[1:], step[1:], last[1:], next_position[1:], views)  # its state before is missing
    with pytest.raises(ValueError, match="last_view -1"):
        view_state(run, step, last, 4)  # score networks: still refused
