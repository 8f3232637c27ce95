"""Published versions: the manifest pins every shard, verify names each missing, changed,
truncated or extra one and refuses shard paths outside the root, versions are immutable, splits
are disjoint and seeded, the card loads a sample, and nbvtrain fits exactly a published version."""

import hashlib
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from conftest import PUBLISHING, about

from nbvdata.cli import main as nbvdata
from nbvdata.core.config import SimConfig, load_config
from nbvdata.datasets.authors import import_legacy
from nbvdata.datasets.generate import generate
from nbvdata.datasets.publish import publish
from nbvdata.schema.manifest import (BUILTIN_LICENSE, NOT_RECORDED, compare, from_ranges, load_manifest, mesh_split,
                                     next_version, random_split, to_ranges)
from nbvdata.schema.shards import Shard
from nbvdata.simulation.sources import builtin_sources, mesh_sources
from nbvtrain.cli import main as nbvtrain
from nbvtrain.networks.training_data import load_shards, split_indices

SMOKE = Path(__file__).resolve().parents[1] / "configs" / "smoke.yaml"
FAST = ["--model", "nbvnet-3-3", "--batch-size", "16", "--threads", "1", "--no-progress"]


def _smoke(*overrides: str) -> SimConfig:
    return load_config(SimConfig, SMOKE, ["generate.workers=1", "episode.max_scans=3", *overrides])


@pytest.fixture(scope="module")
def shards(tmp_path_factory) -> Path:
    """Four built-in shapes x 2 runs of the smoke scene, one run per shard (8 shards, seconds)."""
    out = tmp_path_factory.mktemp("data") / "shards"
    report = generate(builtin_sources()[:4], out, _smoke("episode.runs_per_mesh=2", "generate.runs_per_shard=1"))
    assert not report.failures and len(report.done) == 8
    return out


@pytest.fixture(scope="module")
def published(shards, tmp_path_factory) -> Path:
    """``shards`` published as toy 1.0.0; the path of its manifest. Tests must not change it."""
    manifests = tmp_path_factory.mktemp("site") / "manifests"
    assert nbvdata(["publish", *PUBLISHING, str(shards), "--name", "toy", "--version", "1.0.0", "--notes", "first release",
                    "--manifests", str(manifests)]) == 0
    return manifests / "toy-1.0.0.json"


def _copy(shards: Path, where: Path) -> Path:
    shutil.copytree(shards, where)
    return where


def test_publish_pins_every_shard_mesh_and_setting(shards, published):
    m = json.loads(published.read_text())
    assert (m["name"], m["version"], m["notes"], m["schema_version"]) == ("toy", "1.0.0", "first release", 1)
    assert m["package_version"] == "0.1.0" and m["source"] == "nbvdata generate"
    assert m["git_commit"] is None or re.fullmatch(r"[0-9a-f]{40}", m["git_commit"])
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00", m["created"])
    assert (published.parent / m["root"]).resolve() == shards.resolve() and not Path(m["root"]).is_absolute()
    files = sorted(shards.glob("*.h5"))
    assert [s["path"] for s in m["shards"]] == [p.name for p in files]
    first = 0
    for entry, path in zip(m["shards"], files):
        with Shard(path) as shard:
            assert entry["samples"] == len(shard) and m["config"] == shard.info.config
        assert entry["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
        assert entry["bytes"] == path.stat().st_size and entry["first"] == first
        first += entry["samples"]
    assert m["totals"] == {"shards": 8, "samples": first, "runs": 8, "meshes": 4,
                           "bytes": sum(p.stat().st_size for p in files)}
    assert sorted(mesh["source"] for mesh in m["meshes"]) == sorted(s.name for s in builtin_sources()[:4])
    assert sum(mesh["samples"] for mesh in m["meshes"]) == first
    assert all(mesh["runs"] == 2 and mesh["license"] == BUILTIN_LICENSE for mesh in m["meshes"])


def test_splits_are_disjoint_covering_object_disjoint_and_seeded(shards, published, tmp_path):
    m = load_manifest(published)
    total = m.content["totals"]["samples"]
    random, mesh = m.split("random"), m.split("mesh")
    assert np.array_equal(np.sort(np.concatenate(list(random.values()))), np.arange(total))
    assert np.array_equal(np.sort(np.concatenate(list(mesh.values()))), np.arange(total))
    data = load_shards(m.shard_paths)
    try:
        ids = {part: set(data.mesh_ids[index]) for part, index in mesh.items()}
        assert not ids["train"] & ids["val"] and not ids["train"] & ids["test"] and not ids["val"] & ids["test"]
        assert {part: sorted(ids[part]) for part in ids} == {
            part: m.content["splits"]["mesh"][part]["meshes"] for part in ids}
        assert [len(ids[part]) for part in ("train", "val", "test")] == [2, 1, 1]
        # the random split is the one nbvtrain makes from the same shards with the same seed
        train, val, _ = split_indices(data, "random", 0.2, seed=0)
        assert np.array_equal(random["train"], train) and np.array_equal(random["val"], val)
    finally:
        data.close()
    again = publish(shards, "toy", "1.0.0", tmp_path / "same", about=about())
    other = publish(shards, "toy", "1.0.0", tmp_path / "other", seed=1, about=about())
    assert again.content["splits"] == m.content["splits"] != other.content["splits"]
    assert mesh_split(np.array(["a", "b", "c"]), 0.2, 0.5, 0) == \
        "3 meshes cannot give 1 validation, 2 test and at least 1 training mesh"
    indices = np.sort(random_split(1000, 0.3, 5)[1])
    assert np.array_equal(from_ranges(to_ranges(indices)), indices) and to_ranges([]) == []


def test_card_has_schema_statistics_licenses_and_a_working_h5py_snippet(published, monkeypatch):
    card = published.with_suffix(".md").read_text()
    for heading in ("## How it was made", "## Splits (seed 0)", "## Schema (version 1)", "## Statistics",
                    "## Meshes and licenses", "## Loading a sample with h5py"):
        assert heading in card
    for dataset in ("grids", "grid_palette", "nbv_index", "nbv_position", "gains", "coverage", "mesh_id", "view_poses"):
        assert f"| `{dataset}` | (" in card
    assert "first release" in card and "Observable surface covered at the end of a run" in card
    assert "builtin:mug" in card and BUILTIN_LICENSE in card and "toy-1.0.0.png" in card
    assert published.with_suffix(".png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (snippet,) = re.findall(r"```python\n(.*?)```", card, re.S)
    assert len(snippet.splitlines()) == 5
    monkeypatch.chdir(published.parent.parent)
    scope: dict = {}
    exec(snippet, scope)
    assert scope["grid"].shape == (32, 32, 32) and scope["grid"].dtype == np.float32 and (scope["grid"] == 0.5).any()
    assert np.linalg.norm(scope["nbv"]) == pytest.approx(1.0, abs=1e-6)


def test_fit_holds_out_the_meshes_a_version_does_for_the_same_seed(shards, tmp_path):
    """One mesh split: nbvtrain's on shards is the manifest's with no test part."""
    for seed in (0, 1, 2):
        m = load_manifest(publish(shards, "toy", "1.0.0", tmp_path / str(seed), seed=seed, val_fraction=0.5,
                                  test_fraction=0, about=about()).path)
        data = load_shards(m.shard_paths)
        try:
            train, val, info = split_indices(data, "mesh", 0.5, seed)
        finally:
            data.close()
        published = m.split("mesh")
        assert info["val_meshes"] == m.content["splits"]["mesh"]["val"]["meshes"]
        assert np.array_equal(val, published["val"]) and np.array_equal(train, published["train"])

def test_verify_passes_an_untouched_copy(shards, published, tmp_path, capsys):
    assert nbvdata(["verify", str(published)]) == 0
    copy = _copy(shards, tmp_path / "copy")
    assert nbvdata(["verify", str(published), "--root", str(copy)]) == 0
    assert "ok: every shard is there" in capsys.readouterr().out


def _flip_a_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


TAMPERING = {
    "changed": _flip_a_byte,
    "truncated": lambda path: path.write_bytes(path.read_bytes()[:-100]),
    "missing": Path.unlink,
    "extra": lambda path: shutil.copy(path, path.with_name("zzz-extra.h5")),
}


@pytest.mark.parametrize("kind", TAMPERING)
def test_verify_names_each_tampered_shard(shards, published, tmp_path, capsys, kind):
    copy = _copy(shards, tmp_path / "copy")
    victim = sorted(copy.glob("*.h5"))[3]
    TAMPERING[kind](victim)
    assert nbvdata(["verify", str(published), "--root", str(copy)]) == 1
    lines = capsys.readouterr().out.splitlines()
    named = "zzz-extra.h5" if kind == "extra" else victim.name
    assert [line for line in lines if line.startswith(f"{kind}: ")] == [line for line in lines if named in line]
    assert len([line for line in lines if line.startswith(f"{kind}: {named}")]) == 1
    assert lines[-1].startswith("1 problem (")


def test_verify_names_every_problem_at_once(shards, published, tmp_path, capsys):
    copy = _copy(shards, tmp_path / "copy")
    files = sorted(copy.glob("*.h5"))
    for kind, path in zip(TAMPERING, files):
        TAMPERING[kind](path)
    assert nbvdata(["verify", str(published), "--root", str(copy)]) == 1
    out = capsys.readouterr().out
    for kind, path in zip(TAMPERING, files):
        assert f"{kind}: {'zzz-extra.h5' if kind == 'extra' else path.name}" in out
    assert "4 problems" in out
    assert nbvdata(["verify", str(published), "--root", str(tmp_path / "nowhere")]) == 2


def _rewrite(path: Path, change=None) -> None:
    """Write ``path`` again with gzip level 9 (other bytes, same arrays), ``change``-ing its arrays."""
    import h5py

    with h5py.File(path, "r") as f:
        arrays = {name: f[name][()] for name in f}
        attrs = dict(f.attrs)
    if change is not None:
        change(arrays)
    with h5py.File(path, "w") as f:
        f.attrs.update(attrs)
        for name, data in arrays.items():
            f.create_dataset(name, data=data, compression="gzip" if data.ndim else None,
                             compression_opts=9 if data.ndim else None)


def test_verify_by_content_accepts_other_bytes_with_the_same_arrays(shards, published, tmp_path, capsys):
    copy = _copy(shards, tmp_path / "copy")
    same, other = sorted(copy.glob("*.h5"))[1:3]
    _rewrite(same)
    assert nbvdata(["verify", str(published), "--root", str(copy)]) == 1
    out = capsys.readouterr().out
    assert f"changed: {same.name}: " in out and "same content (every array and attribute equal)" in out
    assert nbvdata(["verify", str(published), "--root", str(copy), "--content"]) == 0
    assert "ok: every shard is there, with the same content" in capsys.readouterr().out

    def nudge(arrays):
        arrays["gains"][0, 0] = np.nextafter(arrays["gains"][0, 0], np.float32(1))

    _rewrite(other, nudge)
    assert nbvdata(["verify", str(published), "--root", str(copy), "--content"]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert [line for line in lines if other.name in line][0].endswith("content differs in gains")
    assert not [line for line in lines if same.name in line]


def test_a_complete_smaller_shard_is_not_called_truncated(shards, published, tmp_path, capsys):
    copy = _copy(shards, tmp_path / "copy")
    files = sorted(copy.glob("*.h5"), key=lambda path: path.stat().st_size)
    smallest, largest = files[0], files[-1]
    size, listed = smallest.stat().st_size, largest.stat().st_size
    assert size < listed
    shutil.copy(smallest, largest)  # a whole, readable shard, only not the one published
    assert nbvdata(["verify", str(published), "--root", str(copy)]) == 1
    out = capsys.readouterr().out
    assert f"changed: {largest.name}: size differs: {size:,} bytes, the manifest lists {listed:,}" in out
    assert "truncated" not in out


def _escaping(published: Path, shards: Path, tmp_path: Path, how: str) -> tuple[Path, Path]:
    """A copy of the shards and a manifest for it whose first shard lies outside the copy: the
    same bytes, so only where it lies is wrong. Returns (manifest, root)."""
    copy = _copy(shards, tmp_path / "copy")
    content = json.loads(published.read_text())
    name = content["shards"][0]["path"]
    outside = tmp_path / "outside"
    outside.mkdir()
    (copy / name).rename(outside / name)
    if how == "link":
        (copy / name).symlink_to(outside / name)
    else:
        content["shards"][0]["path"] = {"dotdot": f"../outside/{name}", "absolute": str(outside / name),
                                        "nested dotdot": f"x/../../outside/{name}",
                                        "windows": f"..\\outside\\{name}"}[how]
    manifest = tmp_path / "manifests" / published.name
    manifest.parent.mkdir()
    manifest.write_text(json.dumps(content))
    return manifest, copy


@pytest.mark.parametrize("how", ["dotdot", "absolute", "nested dotdot", "windows", "link"])
def test_shard_paths_that_leave_the_root_are_refused(shards, published, tmp_path, capsys, how):
    manifest, root = _escaping(published, shards, tmp_path, how)
    assert nbvdata(["verify", str(manifest), "--root", str(root)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(manifest) in err, err
    assert ("outside" in err and "--root" in err) if how == "link" else "leaves the shards' folder" in err
    run = tmp_path / "run"
    assert nbvtrain(["fit", str(manifest), "--root", str(root), "--epochs", "1", "--out", str(run), *FAST]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1 and not run.exists()


@pytest.mark.parametrize("damage", ["no shards", "an entry without bytes", "a number for a path"])
def test_an_incomplete_manifest_is_one_line(published, tmp_path, capsys, damage):
    content = json.loads(published.read_text())
    if damage == "no shards":
        del content["shards"]
    elif damage == "an entry without bytes":
        del content["shards"][1]["bytes"]
    else:
        content["shards"][1]["path"] = 7
    manifest = tmp_path / published.name
    manifest.write_text(json.dumps(content))
    assert nbvdata(["verify", str(manifest), "--root", str(published.parent)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(manifest) in err and "restore the published copy" in err, err


def test_published_versions_are_immutable(shards, tmp_path, capsys):
    manifests = tmp_path / "manifests"
    part = tmp_path / "part"
    part.mkdir()
    for path in sorted(shards.glob("*.h5"))[:6]:
        shutil.copy(path, part)
    args = ["--name", "toy", "--manifests", str(manifests)]
    assert nbvdata(["publish", *PUBLISHING, str(part), *args, "--version", "1.0.0", "--notes", "n"]) == 0
    before = (manifests / "toy-1.0.0.json").read_bytes()
    capsys.readouterr()
    assert nbvdata(["publish", *PUBLISHING, str(part), *args, "--version", "1.0.0", "--notes", "n"]) == 0
    assert "already published, identical" in capsys.readouterr().out
    assert (manifests / "toy-1.0.0.json").read_bytes() == before  # not even the creation time changes

    assert nbvdata(["publish", *PUBLISHING, str(part), *args, "--version", "1.0.0", "--notes", "other"]) == 2
    assert "publish this as 1.0.1 (metadata only" in capsys.readouterr().err
    assert nbvdata(["publish", *PUBLISHING, str(shards), *args, "--version", "1.0.0", "--notes", "n"]) == 2
    err = capsys.readouterr().err
    assert "shards (2 added, 0 removed, 0 changed)" in err and "publish this as 1.1.0 (new meshes or runs" in err
    assert nbvdata(["publish", *PUBLISHING, str(shards), *args, "--version", "1.1.0", "--notes", "n"]) == 0
    assert nbvdata(["publish", *PUBLISHING, str(part), *args, "--version", "1.0.0", "--test-fraction", "0.4"]) == 2
    assert "publish this as 1.2.0" in capsys.readouterr().err  # bumped from the highest version
    assert (manifests / "toy-1.0.0.json").read_bytes() == before

    old = json.loads(before)
    assert compare(old, old | {"created": "later", "git_commit": "f" * 40, "root": "elsewhere"}) == (None, "")
    assert compare(old, old | {"schema_version": 2})[0] == "major"
    relicensed = [mesh | {"license": "CC-BY-4.0"} for mesh in old["meshes"]]
    assert compare(old, old | {"meshes": relicensed}) == ("patch", "licenses")
    assert next_version(manifests, "toy", "major") == "2.0.0"
    assert nbvdata(["publish", *PUBLISHING, str(part), *args, "--version", "1.0"]) == 2
    assert "use X.Y.Z" in capsys.readouterr().err


def test_licenses_come_from_the_meshes_table_and_few_meshes_have_no_mesh_split(tmp_path):
    meshes = tmp_path / "meshes"
    meshes.mkdir()
    trimesh.creation.box(extents=(1, 2, 3)).export(meshes / "box.stl")
    trimesh.creation.icosphere(subdivisions=2).export(meshes / "ball.stl")
    (meshes / "MESHES.tsv").write_text("split\tfile\tlicense_or_origin\ntrain\tbox.stl\tCC0, made by the test\n")
    sources, _ = mesh_sources(meshes)
    assert not generate(sources, tmp_path / "shards", _smoke("episode.runs_per_mesh=1")).failures
    result = publish(tmp_path / "shards", "files", "1.0.0", tmp_path / "manifests", mesh_dir=meshes, about=about())
    licenses = {mesh["source"]: mesh["license"] for mesh in result.content["meshes"]}
    assert licenses == {"box.stl": "CC0, made by the test", "ball.stl": NOT_RECORDED}
    assert result.content["meshes"][1]["sha256"] == hashlib.sha256((meshes / "box.stl").read_bytes()).hexdigest()
    assert result.content["splits"]["mesh"] == {
        "unavailable": "2 meshes cannot give 1 validation, 1 test and at least 1 training mesh"}
    card = (tmp_path / "manifests" / "files-1.0.0.md").read_text()
    assert "| box.stl |" in card and "CC0, made by the test" in card and "--meshes MESH_DIR" in card


def test_publish_with_meshes_but_no_table_says_the_table_is_missing_and_its_columns(tmp_path, capsys):
    meshes = tmp_path / "meshes"
    meshes.mkdir()
    trimesh.creation.box(extents=(1, 2, 3)).export(meshes / "box.stl")
    sources, _ = mesh_sources(meshes)
    assert not generate(sources, tmp_path / "shards", _smoke("episode.runs_per_mesh=1")).failures
    args = ["publish", *PUBLISHING, str(tmp_path / "shards"), "--name", "files", "--manifests", str(tmp_path / "manifests"),
            "--meshes", str(meshes)]
    assert nbvdata([*args, "--version", "1.0.0"]) == 0
    warning = capsys.readouterr().err.strip()
    assert f"--meshes {meshes} has no MESHES.tsv in it or below" in warning and "box.stl" in warning
    assert "columns file and license_or_origin" in warning and "pass --meshes" not in warning
    assert len(warning.splitlines()) == 1
    (meshes / "MESHES.tsv").write_text("file\tlicense_or_origin\nother.stl\tCC0\n")
    assert nbvdata([*args, "--version", "1.0.1"]) == 0
    assert f"add their rows to a MESHES.tsv in or below --meshes {meshes}" in capsys.readouterr().err


def test_imported_shards_publish_with_the_random_split_only(tmp_path, rng, capsys):
    grids = np.full((6, 32 ** 3), 0.5)
    for row in range(6):
        grids[row, : 1000 * (row % 3 + 1)] = 0.7  # runs of 3 states: knowledge grows, then resets
    directions = rng.normal(size=(6, 3))
    poses = np.concatenate([0.4 * directions / np.linalg.norm(directions, axis=1, keepdims=True),
                            np.zeros((6, 3))], axis=1)
    np.save(tmp_path / "dataset_volumes_regression.npy", grids)
    np.save(tmp_path / "dataset_pose.npy", poses)
    import_legacy(tmp_path / "dataset_volumes_regression.npy", tmp_path / "dataset_pose.npy", tmp_path / "shards",
                  rows_per_shard=4, show_progress=False)
    result = publish(tmp_path / "shards", "legacy", "1.0.0", tmp_path / "manifests", about=about())
    m = result.content
    assert m["splits"]["mesh"] == {"unavailable": "the shards hold no mesh ids (imported data)"}
    assert m["splits"]["random"]["train"]["samples"] + m["splits"]["random"]["val"]["samples"] == 6
    assert [mesh["id"] for mesh in m["meshes"]] == [None] and m["meshes"][0]["runs"] == 2
    assert m["source"].startswith("legacy: nbv-regression-2019") and "GPL-3.0" in m["meshes"][0]["source"]
    card = (tmp_path / "manifests" / "legacy-1.0.0.md").read_text()
    assert "imported by `nbvdata import-legacy`" in card and "| `gains` | (N, V) | float32 |" in card
    assert "*(absent in this version)*" in card
    manifest = str(tmp_path / "manifests" / "legacy-1.0.0.json")
    assert nbvtrain(["fit", manifest, "--split", "mesh", "--out", str(tmp_path / "run"), *FAST]) == 2
    assert "no mesh split (the shards hold no mesh ids (imported data)): use --split random" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()  # refused before the run folder is made


def test_fit_trains_on_the_published_split_records_it_and_resumes_exactly(published, tmp_path):
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    assert nbvtrain(["fit", str(published), "--split", "mesh", "--epochs", "2", "--out", str(straight), *FAST]) == 0
    data = json.loads((straight / "data.json").read_text())
    assert data["manifest"] == {"name": "toy", "version": "1.0.0",
                                "sha256": hashlib.sha256(published.read_bytes()).hexdigest(),
                                "path": str(published.resolve()), "root": data["manifest"]["root"]}
    split = load_manifest(published).split("mesh")
    assert data["val_indices"] == split["val"].tolist()
    assert data["train_samples"] == len(split["train"]) and data["samples"] == sum(map(len, split.values()))
    assert data["split"]["test_meshes"] == json.loads(published.read_text())["splits"]["mesh"]["test"]["meshes"]
    assert nbvtrain(["fit", str(published), "--split", "mesh", "--epochs", "1", "--out", str(resumed), *FAST]) == 0
    assert nbvtrain(["fit", "--resume", "--epochs", "2", "--out", str(resumed), "--no-progress"]) == 0
    a, b = (torch.load(run / "last.pt", weights_only=True)["state_dict"] for run in (straight, resumed))
    assert all(torch.equal(a[key], b[key]) for key in a)


def test_fit_refuses_a_tampered_version(shards, published, tmp_path, capsys):
    copy = _copy(shards, tmp_path / "copy")
    victim = sorted(copy.glob("*.h5"))[2]
    _flip_a_byte(victim)
    run = tmp_path / "run"
    assert nbvtrain(["fit", str(published), "--root", str(copy), "--epochs", "1", "--out", str(run), *FAST]) == 2
    err = capsys.readouterr().err
    assert f"changed: {victim.name}: sha256 differs" in err and len(err.strip().splitlines()) == 1
    assert not run.exists()


@pytest.fixture(scope="module")
def clouds(tmp_path_factory) -> Path:
    """Two built-in shapes, one run each with 32-point clouds, published as clouds 1.0.0 (its manifest)."""
    base = tmp_path_factory.mktemp("clouds")
    report = generate(builtin_sources()[:2], base / "shards", _smoke("episode.runs_per_mesh=1", "state.points=32"))
    assert not report.failures
    assert nbvdata(["publish", *PUBLISHING, str(base / "shards"), "--name", "clouds", "--version", "1.0.0",
                    "--manifests", str(base / "manifests")]) == 0
    return base / "manifests" / "clouds-1.0.0.json"


def _nudged(path: Path, array: str) -> None:
    def nudge(arrays):
        arrays[array].flat[0] = np.nextafter(arrays[array].flat[0], np.float32(1))

    _rewrite(path, nudge)


def test_a_grid_network_trains_on_a_version_whose_clouds_alone_differ(clouds, tmp_path, capsys):
    """Hit points can differ in their last bits on another CPU (Embree may report either triangle of
    an edge a ray meets); a network that reads no clouds trains on such a regeneration, one that
    reads them, or any network on a shard whose grids or labels differ, is refused."""
    copy = _copy(clouds.parent.parent / "shards", tmp_path / "copy")
    _nudged(sorted(copy.glob("*.h5"))[0], "points")
    assert nbvdata(["verify", str(clouds), "--root", str(copy)]) == 1
    assert "content differs in points" in capsys.readouterr().out
    fit = ["fit", str(clouds), "--root", str(copy), "--split", "random", "--epochs", "1"]
    assert nbvtrain([*fit, "--out", str(tmp_path / "grid"), *FAST]) == 0
    assert "1 shard differs from the published ones in points only, which this network does not read" in \
        capsys.readouterr().out
    assert nbvtrain([*fit, "--out", str(tmp_path / "cloud"), "--model", "nbvscore-pc", "--batch-size", "16",
                     "--threads", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "content differs in points" in err and "restore them" in err
    _nudged(sorted(copy.glob("*.h5"))[1], "gains")
    assert nbvtrain([*fit, "--out", str(tmp_path / "labels"), *FAST]) == 2
    err = capsys.readouterr().err
    assert "1 shard differs from the published" in err and "content differs in gains" in err
    assert not (tmp_path / "cloud").exists() and not (tmp_path / "labels").exists()


def test_a_refusal_names_a_few_changed_shards_and_counts_the_rest(clouds, tmp_path, monkeypatch):
    """A regeneration that changed every shard is refused in one short line, not one per shard."""
    import nbvdata.schema.manifest as manifest

    copy = _copy(clouds.parent.parent / "shards", tmp_path / "copy")
    for path in sorted(copy.glob("*.h5")):
        _nudged(path, "gains")
    monkeypatch.setattr(manifest, "SHOWN_PROBLEMS", 1)
    with pytest.raises(manifest.ManifestError) as refused:
        manifest.open_verified(clouds, copy)
    message = str(refused.value)
    assert message.startswith(f"{clouds}: 2 shards differ from the published clouds 1.0.0 (")
    assert message.count("content differs in gains") == 1
    assert f"; and 1 more: nbvdata verify {clouds} lists them all): restore them" in message


@pytest.mark.parametrize("older, newer, arrays", [("1.2.0", "1.3.0", {"points"}), ("1.3.0", "1.4.0", {"points"}),
                                                  ("1.4.0", "1.5.0", {"points", "points_count"})])
def test_train_meshes_versions_differ_in_their_clouds_only(older, newer, arrays):
    """The published 1.3.0 (clouds on canonical triangles at edges) against 1.2.0, 1.4.0
    (canonical among every triangle at the same depth) against 1.3.0 and 1.5.0 (grazed outlines
    passed through) against 1.4.0: the same meshes, settings, splits and shards, and in every
    shard the same content digests but for ``points`` (and ``points_count``, where an outline's
    hit passed through to nothing)."""
    root = Path(__file__).resolve().parents[1] / "manifests"
    old, new = (json.loads((root / f"train-meshes-{version}.json").read_text()) for version in (older, newer))
    for key in ("meshes", "config", "splits"):
        assert old[key] == new[key], key
    old_shards = {shard["path"]: shard for shard in old["shards"]}
    assert sorted(old_shards) == sorted(shard["path"] for shard in new["shards"])
    clouds_changed = 0
    for shard in new["shards"]:
        before = old_shards[shard["path"]]
        assert (shard["samples"], shard["runs"]) == (before["samples"], before["runs"])
        differ = {key for key in shard["content"] if shard["content"][key] != before["content"].get(key)}
        assert differ <= arrays, (shard["path"], differ)
        clouds_changed += bool(differ)
    assert clouds_changed > 1000  # nearly every shard has a point near an edge, a duplicated face or crossing parts


def test_publish_records_the_commit_of_the_checkout_it_runs_from():
    """From a git checkout the commit is recorded (after the move into folders it was not: the
    checkout was looked for from nbvdata/schema/)."""
    import subprocess

    from nbvdata.schema.manifest import git_state

    root = Path(__file__).resolve().parents[1]
    done = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip("not run from a git checkout: nothing to record")
    assert git_state()[0] == done.stdout.strip()
