"""``nbvdata export --format scvp``: shards with set-cover labels as SCVP's training folders.

SCVP (Pan et al., RA-L 2022; their sc-net ``VOXELDataset``) trains on one folder per state
holding exactly two files, found by walking the tree:

    DIR/view_space.txt                    32, then one "x y z" line per candidate view (metres, our
                                          radius; shortest round-trip decimals)
    DIR/<shard>/<index>/grid.txt          32,768 occupancy probabilities, one per line
    DIR/<shard>/<index>/view_ids.txt      the state's cover: view indices, one per line

``<shard>`` is the shard's file name without ``.h5``, ``<index>`` the sample's row in it (six
digits). The grid's line order is the C order of our (x, y, z) grid: line i*1024 + j*32 + k is
voxel [i, j, k], i along x, j along y, k along z - the order of SCVP's generator (its loops run
x, then y, then z innermost) and of their readers' ``reshape(32, 32, 32)``. Values are written
with 9 significant digits, so each float32 probability reads back exactly. Only shards of SCVP's
scene export: 32^3 grids, their 32 views (``views.layout: scvp-32``) and ``cover`` labels.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nbvdata.shards import Shard, ShardError
from nbvdata.text import plural

SCVP_VIEWS = 32
SCVP_GRID = 32


@dataclass
class ExportReport:
    states: int = 0
    shards: int = 0


def export_scvp(shard_paths: list[Path], out_dir: Path) -> ExportReport:
    """Write every state of ``shard_paths`` to ``out_dir`` (absent or empty) in SCVP's layout.
    Every shard is checked before anything is written; ShardError names the first that cannot."""
    out_dir = Path(out_dir)
    if out_dir.exists() and any(out_dir.iterdir()):
        raise ShardError(f"{out_dir} is not empty: export into a new --out folder")
    positions = None
    for path in shard_paths:
        with Shard(path) as shard:
            _check(shard)
            here = shard["view_positions"]
            if positions is not None and not np.array_equal(here, positions):
                raise ShardError(f"{path}: other candidate views than {shard_paths[0]}: export shards of one "
                                 "view layout together")
            positions = here
    out_dir.mkdir(parents=True, exist_ok=True)
    lines = [str(len(positions))] + [" ".join(repr(value) for value in row) for row in positions.tolist()]
    (out_dir / "view_space.txt").write_text("\n".join(lines) + "\n")
    report = ExportReport()
    for path in shard_paths:
        with Shard(path) as shard:
            covers = shard["cover"]
            for index in range(len(shard)):
                folder = out_dir / Path(path).stem / f"{index:06d}"
                folder.mkdir(parents=True)
                grid = shard.grids(index).reshape(-1)  # C order of [x, y, z]
                (folder / "grid.txt").write_text("\n".join(f"{value:.9g}" for value in grid.tolist()) + "\n")
                views = np.flatnonzero(covers[index])
                (folder / "view_ids.txt").write_text("".join(f"{view}\n" for view in views))
            report.states += len(shard)
            report.shards += 1
    return report


def _check(shard: Shard) -> None:
    """One line naming the fix for a shard SCVP's format cannot hold."""
    if not shard.has("cover"):
        raise ShardError(f"{shard.path}: no set-cover labels; generate with --set oracle.cover=true to export "
                         "--format scvp")
    views = len(shard["view_positions"])
    if views != SCVP_VIEWS:
        raise ShardError(f"{shard.path}: {plural(views, 'candidate view')}, SCVP's format has their {SCVP_VIEWS}: "
                         "generate with --set views.layout=scvp-32 --set views.count=32")
    size = shard.file["grids"].shape[1]
    if size != SCVP_GRID:
        raise ShardError(f"{shard.path}: {size}^3 grids, SCVP reads {SCVP_GRID}^3: generate with grid.size 32")
