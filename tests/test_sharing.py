"""A published version as the ecosystem reads it: Croissant (mlcroissant validates it and loads
every RecordSet), the Hub card (``datasets.load_dataset`` on the shared folder), CITATION.cff
(``cffconvert --validate``) and .zenodo.json - all offline."""

from __future__ import annotations

import gzip
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import PUBLISHING, about

from nbvdata.cli import main as nbvdata
from nbvdata.core.config import SimConfig, load_config
from nbvdata.datasets.about import load_about
from nbvdata.datasets.croissant import check_croissant
from nbvdata.datasets.generate import generate
from nbvdata.datasets.index import read_index
from nbvdata.datasets.publish import describe
from nbvdata.schema.manifest import ManifestError, load_manifest
from nbvdata.simulation.sources import builtin_sources

SMOKE = Path(__file__).resolve().parents[1] / "configs" / "smoke.yaml"
ZENODO_KEYS = {"upload_type", "title", "creators", "description", "license", "publication_date", "version"}


@pytest.fixture(scope="module")
def version(tmp_path_factory) -> Path:
    """Five built-in shapes x 2 runs, one run per shard, published as tiny 1.0.0 with a test
    part; the manifest's path. Tests must not change it."""
    base = tmp_path_factory.mktemp("site")
    config = load_config(SimConfig, SMOKE, ["generate.workers=1", "episode.max_scans=3", "episode.runs_per_mesh=2",
                                            "generate.runs_per_shard=1"])
    report = generate(builtin_sources()[:5], base / "shards", config)
    assert not report.failures
    assert nbvdata(["publish", str(base / "shards"), *PUBLISHING, "--name", "tiny", "--version", "1.0.0",
                    "--manifests", str(base / "manifests"), "--val-fraction", "0.2", "--test-fraction", "0.2"]) == 0
    return base / "manifests" / "tiny-1.0.0.json"


def test_a_version_without_license_or_creator_is_refused_naming_the_flag(tmp_path, capsys):
    args = ["publish", str(tmp_path), "--name", "x", "--version", "1.0.0", "--url", "https://example.org"]
    assert nbvdata([*args, "--creator", "Lab"]) == 2
    assert "no license: pass --license" in capsys.readouterr().err
    assert nbvdata([*args, "--license", "MIT"]) == 2
    assert "no creator: pass --creator" in capsys.readouterr().err
    with pytest.raises(ManifestError, match="license_text"):
        load_about(license="other", creators=["Lab"], url="https://example.org")
    bad = tmp_path / "about.yaml"
    bad.write_text("license: MIT\ncreators: [Lab]\nurl: https://example.org\nlicence: typo\n")
    with pytest.raises(ManifestError, match="unknown key 'licence'"):
        load_about(bad)


def test_the_croissant_validates_and_every_record_set_loads_the_manifests_counts(version):
    mlcroissant = pytest.importorskip("mlcroissant", reason="the publish extra is not installed: "
                                                           "pip install -e '.[publish]'")
    croissant = version.with_name("tiny-1.0.0.croissant.json")
    command = Path(sys.executable).with_name("mlcroissant")  # the package's own command, beside this Python
    validate = subprocess.run([str(command), "validate", "--jsonld", str(croissant)], capture_output=True, text=True)
    assert validate.returncode == 0, validate.stderr[-2000:]
    assert "WARNING" not in validate.stderr and "error" not in validate.stderr.lower()
    document = json.loads(croissant.read_text())
    assert document["conformsTo"] == ["http://mlcommons.org/croissant/1.1", "http://mlcommons.org/croissant/RAI/1.0"]
    for key in ("name", "description", "license", "url", "creator", "datePublished", "version", "citeAs"):
        assert document[key], key
    content = load_manifest(version).content
    dataset = mlcroissant.Dataset(croissant)
    samples = list(dataset.records("samples"))
    assert len(samples) == content["totals"]["samples"]
    assert [row["samples/key"] for row in samples] == list(range(len(samples)))
    mesh_split = content["splits"]["mesh"]
    for part in ("train", "val", "test"):
        assert sum(row["samples/mesh_split"] == part.encode() for row in samples) == mesh_split[part]["samples"]
    assert [row["splits/name"] for row in dataset.records("splits")] == ["train", "val", "test"]
    assert len(list(dataset.records("meshes"))) == len(content["meshes"])
    shards = {item["name"]: item for item in document["distribution"] if item["@id"].startswith("shard/")}
    assert {entry["path"]: entry["sha256"] for entry in content["shards"]} == {
        name: item["sha256"] for name, item in shards.items()}


def test_the_index_is_the_shards_rows_and_a_changed_byte_fails_on_load(version, tmp_path):
    mlcroissant = pytest.importorskip("mlcroissant", reason="the publish extra is not installed: "
                                                           "pip install -e '.[publish]'")
    from nbvdata.schema.shards import Shard

    content = load_manifest(version).content
    rows = read_index(version.with_name("tiny-1.0.0.samples.csv.gz").read_bytes())
    published = load_manifest(version)
    for entry, path in zip(content["shards"], published.shard_paths):
        with Shard(path) as shard:
            mine = [row for row in rows if row["shard"] == entry["path"]]
            assert [row["nbv_index"] for row in mine] == shard["nbv_index"].tolist()
            assert [row["scan"] for row in mine] == shard["step"].tolist()
            assert np.array_equal(np.array([row["coverage"] for row in mine], dtype=np.float32), shard["coverage"][:, 0])
    # a copy of the version whose index lost one byte: mlcroissant's sha256 check refuses it on load
    site = tmp_path / "site"
    shutil.copytree(version.parent, site / "manifests")
    index = site / "manifests" / "tiny-1.0.0.samples.csv.gz"
    text = gzip.decompress(index.read_bytes()).replace(b",1,", b",2,", 1)
    index.write_bytes(gzip.compress(text, mtime=0))
    shutil.copytree(published.root, site / "manifests" / content["root"])
    with pytest.raises(Exception, match="Download|sha256|hash"):
        list(mlcroissant.Dataset(site / "manifests" / "tiny-1.0.0.croissant.json").records("samples"))


def test_a_changed_shard_byte_fails_the_croissants_sha256(version, tmp_path, capsys):
    share = tmp_path / "shared"
    assert nbvdata(["share", str(version), "--out", str(share)]) == 0
    croissant = share / "tiny-1.0.0.croissant.json"
    assert nbvdata(["verify", str(croissant)]) == 0
    shard = sorted((share / "shards").glob("*.h5"))[0]
    data = bytearray(shard.read_bytes())
    data[-1] ^= 1
    shard.write_bytes(bytes(data))
    capsys.readouterr()
    assert nbvdata(["verify", str(croissant)]) == 1
    assert f"changed: shards/{shard.name}: sha256 differs from the Croissant's" in capsys.readouterr().out
    # and the manifest's own check names the Croissant that no longer agrees with it
    manifest = share / "tiny-1.0.0.json"
    document = json.loads(croissant.read_text())
    document["distribution"][1]["sha256"] = "0" * 64
    croissant.write_text(json.dumps(document))
    assert nbvdata(["verify", str(manifest), "--root", str(share / "shards")]) == 1
    assert "sha256 or size differs from the manifest's" in capsys.readouterr().out
    # a contentUrl that leaves the Croissant's folder is named, and the file there is not read
    (tmp_path / "outside.h5").write_bytes(b"not a shard")
    document["distribution"][1]["contentUrl"] = "../outside.h5"
    croissant.write_text(json.dumps(document))
    assert nbvdata(["verify", str(croissant)]) == 1
    assert "outside: ../outside.h5: a contentUrl leaves the Croissant's folder" in capsys.readouterr().out


def test_the_shared_folder_loads_with_datasets_as_the_splits_of_the_manifest(version, tmp_path):
    datasets = pytest.importorskip("datasets", reason="the publish extra is not installed: pip install -e '.[publish]'")
    share = tmp_path / "hub"
    assert nbvdata(["share", str(version), "--out", str(share)]) == 0
    front = yaml.safe_load((share / "README.md").read_text().split("---\n")[1])
    assert front["license"] == "cc-by-4.0" and front["pretty_name"] == "tiny 1.0.0"
    assert {"license", "tags", "task_categories", "size_categories", "configs"} <= front.keys()
    loaded = datasets.load_dataset(str(share), cache_dir=str(tmp_path / "cache"))
    split = load_manifest(version).content["splits"]["mesh"]
    assert {name: len(part) for name, part in loaded.items()} == {
        "train": split["train"]["samples"], "validation": split["val"]["samples"], "test": split["test"]["samples"]}
    feature = loaded["train"].features["grid"]
    assert type(feature).__name__ == "Array3D" and feature.shape == (32, 32, 32) and feature.dtype == "float32"
    # the grid of a row is the shard's, decoded
    from nbvdata.schema.manifest import load_manifest as manifest_of
    from nbvdata.schema.shards import Shard

    row = loaded["test"].with_format("numpy")[0]
    published = manifest_of(version)
    for entry, path in zip(published.content["shards"], published.shard_paths):
        if entry["first"] <= row["key"] < entry["first"] + entry["samples"]:
            with Shard(path) as shard:
                assert (shard.grids(int(row["key"] - entry["first"])) == row["grid"]).all()
            break
    else:
        pytest.fail("the row's key is no sample of the version")


def test_the_citation_files_validate(version):
    cffconvert = Path(sys.executable).with_name("cffconvert")
    if not cffconvert.exists():
        pytest.skip("cffconvert is not installed: pip install -e '.[publish]'")
    check = subprocess.run([str(cffconvert), "--validate", "-i", str(version.with_suffix(".cff"))], capture_output=True,
                           text=True)
    assert check.returncode == 0, check.stdout + check.stderr
    cff = yaml.safe_load(version.with_suffix(".cff").read_text())
    assert cff["type"] == "dataset" and cff["authors"] == [{"family-names": "Lovelace", "given-names": "Ada"}]
    zenodo = json.loads(version.with_suffix(".zenodo.json").read_text())
    assert ZENODO_KEYS <= zenodo.keys() and zenodo["upload_type"] == "dataset"
    assert zenodo["creators"] == [{"name": "Lovelace, Ada"}] and zenodo["license"] == "cc-by-4.0"


def test_describing_a_published_version_again_gives_the_same_bytes(version, tmp_path):
    """What ``nbvdata publish MANIFEST`` writes for a version already published: the same
    files as publishing it did, the manifest untouched."""
    copy = tmp_path / "manifests"
    shutil.copytree(version.parent, copy)
    before = {path.name: path.read_bytes() for path in copy.iterdir()}
    root = load_manifest(version).root
    written = describe(copy / version.name, about(), root)
    assert {path.name for path in written} == {"tiny-1.0.0.md", "tiny-1.0.0.samples.csv.gz", "tiny-1.0.0.cff",
                                               "tiny-1.0.0.croissant.json", "tiny-1.0.0.zenodo.json"}
    assert {path.name: path.read_bytes() for path in copy.iterdir()} == before


ROOT = Path(__file__).resolve().parents[1]
COMMITTED = sorted(path for path in (ROOT / "manifests").glob("*.json")
                   if re.fullmatch(r".+-\d+\.\d+\.\d+\.json", path.name))
WITHOUT = {"builtin-shapes-1.0.0": "a record only: no regeneration can prove its rows"}
# docs/publishing.md, "Croissant, the Hub and citations"


@pytest.mark.parametrize("manifest", COMMITTED, ids=[path.stem for path in COMMITTED])
def test_every_committed_version_has_its_croissant_index_hub_card_and_citation(manifest):
    content = load_manifest(manifest).content
    croissant = manifest.with_name(f"{manifest.stem}.croissant.json")
    if manifest.stem in WITHOUT:
        assert not croissant.exists(), f"{manifest.stem} has its Croissant now: take it off WITHOUT"
        return
    assert check_croissant(croissant, content) == []  # every shard's sha256 the manifest's; the index's its own
    rows = read_index(manifest.with_name(f"{manifest.stem}.samples.csv.gz").read_bytes())
    assert [row["key"] for row in rows] == list(range(content["totals"]["samples"]))
    for kind, column in (("mesh", "mesh_split"), ("random", "random_split")):
        for part in ("train", "val", "test"):
            if part in content["splits"][kind]:
                assert sum(row[column] == part for row in rows) == content["splits"][kind][part]["samples"]
    front = yaml.safe_load(manifest.with_suffix(".md").read_text().split("---\n")[1])
    assert front["pretty_name"] == f"{content['name']} {content['version']}" and front["license"] == "other"
    assert [split["split"] for split in front["configs"][0]["data_files"]] == ["train", "validation", "test"][
        :len(front["configs"][0]["data_files"])]
    assert yaml.safe_load(manifest.with_suffix(".cff").read_text())["version"] == content["version"]
    assert ZENODO_KEYS <= json.loads(manifest.with_suffix(".zenodo.json").read_text()).keys()
    mlcroissant = pytest.importorskip("mlcroissant", reason="the publish extra is not installed: "
                                                           "pip install -e '.[publish]'")
    first = next(iter(mlcroissant.Dataset(croissant).records("samples")))  # what the NeurIPS validator loads
    holder = next(entry["path"] for entry in content["shards"] if entry["samples"])  # a shard may hold none
    assert first["samples/key"] == 0 and first["samples/shard"].decode() == holder


def _rewritten(path: Path, array: str | None = None, added: dict | None = None) -> None:
    """``path`` written again at another gzip level (other bytes), ``array``'s first value changed,
    the arrays ``added`` (name -> values) added."""
    import h5py

    with h5py.File(path, "r") as f:
        arrays, attrs = {name: f[name][()] for name in f} | (added or {}), dict(f.attrs)
    if array is not None:  # a change within the array's value rules
        values = arrays[array]
        first = values.flat[0]
        values.flat[0] = (np.nextafter(first, values.dtype.type(first < 1)) if values.dtype.kind == "f"
                          else int(first == 0))
    with h5py.File(path, "w") as f:
        f.attrs.update(attrs)
        for name, data in arrays.items():
            f.create_dataset(name, data=data, compression="gzip" if data.ndim else None,
                             compression_opts=9 if data.ndim else None)


def test_the_index_of_a_version_reads_shards_whose_other_arrays_or_bytes_differ(version, tmp_path):
    """Another version of the same states (the covers of a layout's states, a later version with
    point clouds, a regeneration by another HDF5 library) gives the index: what it reads is proved
    equal by the manifest's digests; a shard whose labels differ is refused, naming it."""
    published = load_manifest(version)
    copy = tmp_path / "manifests"
    shutil.copytree(version.parent, copy)
    index = copy / "tiny-1.0.0.samples.csv.gz"
    expected = index.read_bytes()
    root = tmp_path / "other"
    shutil.copytree(published.root, root)
    first, second, third = sorted(root.glob("*.h5"))[:3]
    _rewritten(first)  # other bytes, every array equal
    _rewritten(second, "gains")  # an array the index does not read
    _rewritten(third, added={"surface": np.ones((4, 4, 4), bool)})  # an array the manifest does not record
    describe(copy / version.name, about(), root)
    assert index.read_bytes() == expected
    from nbvdata.schema.manifest import verify

    assert {problem.arrays for problem in verify(copy / version.name, root).problems} == {
        (), ("gains",), ("surface",)}
    _rewritten(second, "nbv_index")
    with pytest.raises(ManifestError, match=f"changed: {second.name}: .*content differs in .*nbv_index"):
        describe(copy / version.name, about(), root)
