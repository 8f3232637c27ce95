"""A shard damaged inside its compressed data (the same size, bytes overwritten in the middle of
a chunk) fails every command that reads it with one line naming the shard and the fix, exit 2:
never an HDF5 traceback, whether the grids are read up front, lazily, or in fit's prefetch
thread."""

from pathlib import Path

import h5py
import numpy as np
import pytest

from nbvdata.cli import main as nbvdata
from nbvdata.shards import Shard, ShardError
from nbvtrain.cli import main as nbvtrain
from nbvtrain.dataset import NBVDataset

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
