"""A shard damaged inside its compressed data (the same size, bytes overwritten in the middle of
a chunk) fails every command that reads it with one line naming the shard and the fix, exit 2:
never an HDF5 traceback, whether the grids are read up front, lazily, or in fit's prefetch
thread."""

from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import PUBLISHING

from nbvdata.cli import main as nbvdata
from nbvdata.schema.shards import Shard, ShardError
from nbvtrain.cli import main as nbvtrain
from nbvtrain.networks.dataset import NBVDataset

ROOT = Path(__file__).resolve().parents[1]
FAST = ["--epochs", "1", "--model", "nbvnet-3-3", "--batch-size", "8", "--threads", "1", "--no-progress"]
ROW = 1  # the damaged sample of the damaged shard


def damage(path: Path, dataset: str, row: int) -> None:
    """Overwrite 32 bytes in the middle of ``row``'s compressed chunk of ``dataset``, in place."""
    size = path.stat().st_size
    with h5py.File(path, "r") as f:
        chunk = f[dataset].id.get_chunk_info_by_coord((row,) + (0,) * (f[dataset].ndim - 1))
    with open(path, "r+b") as handle:
        handle.seek(chunk.byte_offset + chunk.size // 2)
        handle.write(np.random.default_rng(0).bytes(32))
    assert path.stat().st_size == size


@pytest.fixture(scope="module")
def shards(tmp_path_factory) -> tuple[Path, Path]:
    """(folder of smoke shards, the one whose grid ``ROW`` is damaged)."""
    out = tmp_path_factory.mktemp("damaged") / "shards"
    assert nbvdata(["generate", "--config", str(ROOT / "configs" / "smoke.yaml"), "--runs-per-mesh", "2",
                    "--out", str(out), "--no-progress"]) == 0
    victim = sorted(out.glob("*.h5"))[0]
    damage(victim, "grids", ROW)
    return out, victim


COMMANDS = {
    "inspect --by-step": (nbvdata, ["inspect", "--by-step", "{shards}"]),
    "show": (nbvdata, ["show", "{victim}", "--index", str(ROW), "--out", "{tmp}/show.png"]),
    "baselines": (nbvtrain, ["baselines", "{shards}"]),
    "fit": (nbvtrain, ["fit", "{shards}", *FAST, "--out", "{tmp}/run"]),
    "fit, lazy (prefetch thread)": (nbvtrain, ["fit", "{shards}", *FAST, "--set", "memory_limit_gb=0",
                                               "--out", "{tmp}/lazy"]),
    "predict": (nbvtrain, ["predict", "{victim}", "--index", str(ROW)]),
}


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_command_names_the_damaged_shard_in_one_line(shards, command, tmp_path, capsys):
    folder, victim = shards
    main, argv = COMMANDS[command]
    argv = [arg.format(shards=folder, victim=victim, tmp=tmp_path) for arg in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"error: {victim}: damaged, dataset grids cannot be read" in err
    assert err.endswith("delete it and run nbvdata generate again, or restore it from its published version "
                        "(nbvdata verify names every damaged shard)")


def test_the_dataset_class_names_it_too(shards):
    folder, victim = shards
    with pytest.raises(ShardError, match=f"{victim}: damaged, dataset grids"):
        NBVDataset(folder)
    lazy = NBVDataset(folder, memory_limit_gb=0)  # reads at each item: only the damaged sample fails
    try:
        lazy[0]
        with pytest.raises(ShardError, match=f"{victim}: damaged, dataset grids"):
            lazy[ROW]
    finally:
        lazy.close()


def test_only_the_damaged_chunk_fails(shards):
    _, victim = shards
    with Shard(victim) as shard:
        assert shard.grids(0).shape == (32, 32, 32) and len(shard["nbv_index"]) == len(shard)
        for read in (lambda: shard.grids(ROW), lambda: shard.codes(), lambda: shard["grids"],
                     lambda: shard.read("grids", ROW), shard.content_digests):
            with pytest.raises(ShardError, match="damaged, dataset grids cannot be read"):
                read()


def test_plain_inspect_names_damaged_labels_before_printing_anything(shards, tmp_path, capsys):
    """Plain inspect reads every dataset but the grids: damaged gains are named as damaged grids are."""
    folder, _ = shards
    copy = tmp_path / sorted(folder.glob("*.h5"))[1].name
    copy.write_bytes(sorted(folder.glob("*.h5"))[1].read_bytes())
    damage(copy, "gains", 0)
    assert nbvdata(["inspect", str(copy)]) == 2
    printed = capsys.readouterr()
    assert printed.out == "" and len(printed.err.strip().splitlines()) == 1
    assert f"error: {copy}: damaged, dataset gains cannot be read" in printed.err


# ---------------------------------------------------------------------------------------------
# Damage that no gzip stream sees: the per-shard arrays, the attributes, values out of range


def _chunk_offset(path: Path, dataset: str) -> int:
    """Byte offset of the (first) chunk of ``dataset``, or of its contiguous data."""
    with h5py.File(path, "r") as f:
        data = f[dataset]
        return data.id.get_offset() if data.chunks is None else data.id.get_chunk_info(0).byte_offset


def _overwrite(path: Path, offset: int, data: bytes) -> None:
    size = path.stat().st_size
    with open(path, "r+b") as handle:
        handle.seek(offset)
        handle.write(data)
    assert path.stat().st_size == size


def _without_checksums(path: Path, out: Path) -> Path:
    """``path`` rewritten as shards were before issue 50: contiguous per-shard arrays, no
    Fletcher-32, no attributes' digest (to test what readers check in such a shard)."""
    from nbvdata.schema.shards import ATTRIBUTES_DIGEST, PER_SHARD

    with h5py.File(path, "r") as src, h5py.File(out, "w", libver=("earliest", "v110")) as dst:
        for key, value in src.attrs.items():
            if key != ATTRIBUTES_DIGEST:
                dst.attrs[key] = value
        for name in src:
            data = src[name][()]
            if name in PER_SHARD:
                dst.create_dataset(name, data=data, track_times=False)
            else:
                dst.create_dataset(name, data=data, chunks=src[name].chunks, compression="gzip", track_times=False)
    return out


@pytest.fixture(scope="module")
def cloud_shard(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("clouds") / "shards"
    assert nbvdata(["generate", "--config", str(ROOT / "configs" / "smoke.yaml"), "--runs-per-mesh", "2",
                    "--set", "state.points=64", "--out", str(out), "--no-progress"]) == 0
    return sorted(out.glob("*.h5"))[0]


def test_every_dataset_and_chunk_carries_a_checksum(cloud_shard):
    with h5py.File(cloud_shard, "r") as f:
        assert all(f[name].fletcher32 for name in f), [name for name in f if not f[name].fletcher32]
        assert f["reference_points"].chunks == f["reference_points"].shape
    with Shard(cloud_shard) as shard:
        shard.check()


READERS = {  # a command that reads the array
    "grid_palette": ["inspect", "--by-step", "{copy}"],
    "reference_points": ["export", "{copy}", "--format", "pc-nbv", "--out", "{tmp}/export"],
    "view_positions": ["show", "{copy}", "--index", "0", "--out", "{tmp}/show.png"],
    "view_poses": ["publish", *(arg.replace("{", "{{").replace("}", "}}") for arg in PUBLISHING),  # literal {name}
                   "{folder}", "--name", "x", "--version", "1.0.0", "--manifests", "{tmp}/manifests"],
}


@pytest.mark.parametrize("dataset", list(READERS))
def test_damage_to_an_uncompressed_array_fails_its_checksum_in_one_line(cloud_shard, tmp_path, dataset, capsys):
    """4,096 bytes (or the whole array, if smaller) overwritten inside an array that is not gzip'd
    (before the checksums such damage was read with exit 0; export wrote NaN rows)."""
    copy = tmp_path / "folder" / cloud_shard.name
    copy.parent.mkdir()
    copy.write_bytes(cloud_shard.read_bytes())
    with h5py.File(copy, "r") as f:
        nbytes = f[dataset].id.get_storage_size()
    _overwrite(copy, _chunk_offset(copy, dataset) + max(nbytes // 2 - 2048, 0),
               np.random.default_rng(1).bytes(min(4096, nbytes - 8)))
    with Shard(copy) as shard, pytest.raises(ShardError, match=f"damaged, dataset {dataset} cannot be read"):
        shard.read(dataset)
    argv = [arg.format(copy=copy, folder=copy.parent, tmp=tmp_path) for arg in READERS[dataset]]
    assert nbvdata(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"damaged, dataset {dataset}" in err and "Traceback" not in err
    assert nbvdata(["verify", str(copy.parent)]) == 1
    out = capsys.readouterr().out
    assert f"damaged: {copy}: damaged, dataset {dataset} cannot be read" in out and "1 damaged shard of 1" in out


def test_a_palette_out_of_range_is_refused_in_a_shard_without_checksums(cloud_shard, tmp_path, capsys):
    """The issue's case: two palette floats set to NaN and 7.5 in a shard of the old format (no
    checksum to catch it): every read of the palette refuses it, so fit stops in one line."""
    old = _without_checksums(cloud_shard, tmp_path / cloud_shard.name)
    _overwrite(old, _chunk_offset(old, "grid_palette") + 4, np.array([np.nan, 7.5], "<f4").tobytes())
    with Shard(old) as shard:  # opens: only the palette is wrong
        with pytest.raises(ShardError, match="dataset grid_palette: 1 values are not finite"):
            shard.palette
    assert nbvtrain(["fit", str(old), *FAST, "--model", "nbvscore-fc3", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "grid_palette" in err and not (tmp_path / "run").exists()


def test_points_that_are_not_finite_are_refused(cloud_shard, tmp_path, capsys):
    old = _without_checksums(cloud_shard, tmp_path / cloud_shard.name)
    _overwrite(old, _chunk_offset(old, "reference_points") + 120, np.full(8, np.inf, "<f4").tobytes())
    assert nbvdata(["export", str(old), "--format", "pc-nbv", "--out", str(tmp_path / "export")]) == 2
    assert "dataset reference_points: 8 values are not finite" in capsys.readouterr().err
    assert not list((tmp_path / "export").rglob("gt.xyz"))


def test_damaged_attributes_fail_their_checksum(cloud_shard, tmp_path):
    """A digit of the settings changed in place: the YAML still parses, the digest does not match."""
    copy = tmp_path / cloud_shard.name
    data = bytearray(cloud_shard.read_bytes())
    at = data.find(b"min_overlap: 0.2")
    assert at > 0
    data[at + len("min_overlap: 0.")] = ord("3")
    copy.write_bytes(bytes(data))
    with pytest.raises(ShardError, match="damaged, its attributes do not match their checksum"):
        Shard(copy)


def test_verify_reads_a_folder_without_a_manifest(cloud_shard, capsys):
    assert nbvdata(["verify", str(cloud_shard.parent)]) == 0
    assert "every checksum and value range holds" in capsys.readouterr().out
    assert nbvdata(["verify", str(cloud_shard.parent), "--content"]) == 2


def test_a_resumed_generate_redoes_a_shard_that_fails_its_checks(tmp_path, capsys):
    """Damage that opening a shard does not see - a palette chunk, a gzip chunk - is found by
    the resumed job, which makes the shard again: the same bytes as first written."""
    out = tmp_path / "shards"
    argv = ["generate", "--config", str(ROOT / "configs" / "smoke.yaml"), "--runs-per-mesh", "2", "--out", str(out),
            "--no-progress"]
    assert nbvdata(argv) == 0
    first, second = sorted(out.glob("*.h5"))[:2]
    before = {path.name: path.read_bytes() for path in (first, second)}
    _overwrite(first, _chunk_offset(first, "grid_palette") + 4, np.array([np.nan, 7.5], "<f4").tobytes())
    damage(second, "grids", 1)
    capsys.readouterr()
    assert nbvdata(argv) == 0
    printed = capsys.readouterr().out
    assert f"redoing {first.name}" in printed and f"redoing {second.name}" in printed
    assert {path.name: path.read_bytes() for path in (first, second)} == before


def test_plain_inspect_says_it_did_not_read_the_grids_and_names_verify(shards, capsys):
    """Issue 58: plain inspect of a shard with damaged grids printed normal statistics and exit 0
    as if the shards were fine. It still reads only the labels (a fraction of the time), and says
    so, naming the command that reads every byte, which then names the damaged shard."""
    folder, victim = shards
    assert nbvdata(["inspect", str(folder)]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last == (f"checked: only the labels counted above, not the grids (--by-step reads those too); "
                    f"nbvdata verify {folder} reads every shard whole")
    assert nbvdata(["verify", str(folder)]) == 1
    assert f"{victim}: damaged, dataset grids cannot be read" in capsys.readouterr().out
