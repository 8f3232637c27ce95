"""Shards in other projects' file layouts: ``nbvdata export SHARDS_OR_MANIFEST --format F --out DIR``.

``FORMATS`` maps a format's name to its writer, ``writer(shards, out)``: it reads the shards
(files, in order) and writes the format's files under ``out``, an empty folder; ``export``
checks the sources and the folder, runs the writer into ``out.partial`` and renames it to
``out`` when it is whole, so a failed or interrupted export leaves nothing half written.

pc-nbv - the layout PC-NBV's data generator writes and its LMDB writer reads (Zeng et al. 2020,
``generate_nbv_data.py`` and ``lmdb_write_shapenet.py`` in their repository)::

    DIR/viewspace.txt                           (V, 3) the candidate views' unit directions, one
                                                "x y z" a line (np.savetxt), object frame, z up
    DIR/<mesh>/gt.xyz                           (R, 3) the mesh's coverage reference points
                                                (``reference_points``), np.savetxt
    DIR/<mesh>/<run>/<step-1>_viewstate.npy     (V,) int64: 1 scanned before the state, 0 not
    DIR/<mesh>/<run>/<step-1>_acc_pc.npy        (n, 3) float64: the state's cloud - every scanned
                                                point when there were at most state.points of them
                                                (``points_count`` rows), else the state.points of
                                                farthest-point sampling
    DIR/<mesh>/<run>/<step-1>_target_value.npy  (V, 1) float64: every view's gain (``gains``)

``<mesh>`` is the shard's name stem before the run range (the mesh file's stem and the first 12
hex digits of its sha256), ``<run>`` the run number; ``<step-1>`` counts from 0 as their scan
index does (0: the start view scanned). The dtypes are those their generator saves (``np.int``,
open3d's float64 points, ``np.zeros`` float64). Coordinates are nbvdata's object frame in metres
(z up; the object's largest side ``mesh.object_size``), not PC-NBV's unit-size ShapeNet frame:
a network only sees them relative to each other. The gains are the observable coverage a view
would add (``nbvdata.simulation.oracle``), where PC-NBV's target is the share of ground-truth points its
new points cover: the same quantity up to the reference set. Their LMDB writer reads runs
0..ex_times-1 and scans 0..num_scans-1 of every model: shards whose runs stop early (every run
has ``episode.max_scans`` states with ``--set episode.min_gain=0``) need those numbers set per
model, or the missing files skipped.

scvp - the folders SCVP's sc-net trains on (Pan et al. 2022, their ``VOXELDataset``), one per
state, found by walking the tree; only shards of SCVP's scene export: 32^3 grids, their 32 views
(``views.layout: scvp-32``) and set-cover labels (``oracle.cover``)::

    DIR/view_space.txt                    32, then one "x y z" line per candidate view (metres, our
                                          radius; shortest round-trip decimals)
    DIR/<shard>/<index>/grid.txt          32,768 occupancy probabilities, one per line
    DIR/<shard>/<index>/view_ids.txt      the state's cover: view indices, one per line

``<shard>`` is the shard's file name without ``.h5``, ``<index>`` the sample's row in it (six
digits). The grid's line order is the C order of our (x, y, z) grid: line i*1024 + j*32 + k is
voxel [i, j, k], i along x, j along y, k along z - the order of SCVP's generator (its loops run
x, then y, then z innermost) and of their readers' ``reshape(32, 32, 32)``. Values are written
with 9 significant digits, so each float32 probability reads back exactly.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np

from nbvdata.core.text import plural
from nbvdata.schema.shards import Shard, ShardError, cloud_points, shard_files, view_state

PARTIAL_SUFFIX = ".partial"
T = TypeVar("T")


@dataclass
class ExportReport:
    """What an export wrote: ``files`` in all, ``states`` exported, ``meshes``, ``runs``."""

    out: Path
    files: int = 0
    states: int = 0
    meshes: int = 0
    runs: int = 0


def export(sources: list[Path], fmt: str, out: Path, root: Path | None = None) -> ExportReport:
    """Export shards (files or folders) or one published version (a NAME-X.Y.Z.json manifest,
    its shards verified first, under ``root``) in format ``fmt`` of ``FORMATS`` to the new
    folder ``out``. ShardError (one line naming the fix) for an unknown format, an ``out`` that
    holds files, or shards the format cannot use."""
    if fmt not in FORMATS:
        raise ShardError(f"--format {fmt!r}: unknown format; choose one of {', '.join(FORMATS)}")
    out = Path(out)
    check_new_folder(out)
    paths = _shard_paths(sources, root)
    report = write_folder(out, lambda partial: FORMATS[fmt](paths, partial))
    report.out = out
    return report


def check_new_folder(out: Path) -> None:
    """ShardError unless ``out`` is free to write: absent, or an empty folder."""
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ShardError(f"--out {out}: exists and is not an empty folder; name a new folder")


def write_folder(out: Path, fill: Callable[[Path], T]) -> T:
    """``fill(partial)`` writes a folder's files into ``out.partial``, renamed to ``out`` when it
    returns: a failed or interrupted writer leaves nothing half written (what a killed one left
    is cleared first). Returns what ``fill`` does."""
    partial = out.with_name(out.name + PARTIAL_SUFFIX)
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir(parents=True)
    try:
        result = fill(partial)
        if out.exists():
            out.rmdir()
        os.replace(partial, out)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return result


def _shard_paths(sources: list[Path], root: Path | None) -> list[Path]:
    """The shards of ``sources``: one manifest (verified) or shard files and folders."""
    sources = [Path(source) for source in sources]
    if len(sources) == 1 and sources[0].suffix == ".json":
        from nbvdata.schema.manifest import open_verified

        return open_verified(sources[0], root).shard_paths
    if root is not None:
        raise ShardError("--root applies to a manifest (NAME-X.Y.Z.json): leave it out with shard files or folders")
    return shard_files(sources)


def mesh_folder_name(shard: Path) -> str:
    """The ``<mesh>`` folder of a generated shard's states: its name before ``-runsAAAA-BBBB``."""
    stem = shard.stem
    head, separator, tail = stem.rpartition("-runs")
    return head if separator and tail.replace("-", "").isdigit() else stem


def write_pc_nbv(paths: list[Path], out: Path) -> ExportReport:
    """The ``pc-nbv`` format (see the module docstring) of shards ``paths`` under ``out``."""
    report = ExportReport(out)
    views, meshes, runs = None, set(), set()
    for path in paths:
        with Shard(path) as shard:
            if not cloud_points(shard.info.config) or not shard.has("points"):
                raise ShardError(f"{path}: holds no point clouds (made with state.points 0): generate the shards "
                                 "with --set state.points=1024 to export them for PC-NBV")
            if not shard.has("gains") or not shard.has("last_view"):
                raise ShardError(f"{path}: holds no gains or last_view (imported data): export shards written by "
                                 "nbvdata generate")
            positions = shard["view_positions"]
            directions = positions / np.linalg.norm(positions, axis=1, keepdims=True)
            if views is None:
                views = directions
                np.savetxt(out / "viewspace.txt", views)
                report.files += 1
            elif views.shape != directions.shape or not np.allclose(views, directions, atol=1e-12):
                raise ShardError(f"{path}: has other candidate views than {paths[0]}: export one view set at a time")
            run, step, last_view = shard["run"], shard["step"], shard["last_view"]
            try:
                taken = view_state(run, step, last_view, len(positions))
            except ValueError as error:
                raise ShardError(f"{path}: {error}") from None
            mesh = mesh_folder_name(path)
            folder = out / mesh
            if mesh not in meshes:
                folder.mkdir()
                np.savetxt(folder / "gt.xyz", shard["reference_points"].astype(np.float64))
                meshes.add(mesh)
                report.files += 1
            points, counts, gains = shard["points"], shard["points_count"], shard["gains"]  # read once, whole
            for i in range(len(shard)):
                run_folder = folder / str(int(run[i]))
                if (mesh, int(run[i])) not in runs:
                    run_folder.mkdir()
                    runs.add((mesh, int(run[i])))
                scan = int(step[i]) - 1
                cloud = points[i][:min(int(counts[i]), len(points[i]))]  # as Shard.cloud(i)
                np.save(run_folder / f"{scan}_viewstate.npy", taken[i].astype(np.int64))
                np.save(run_folder / f"{scan}_acc_pc.npy", cloud.astype(np.float64))
                np.save(run_folder / f"{scan}_target_value.npy", gains[i].astype(np.float64).reshape(-1, 1))
                report.files += 3
                report.states += 1
    report.meshes, report.runs = len(meshes), len(runs)
    return report


SCVP_VIEWS, SCVP_GRID = 32, 32  # SCVP's network reads 32 candidate views and 32^3 grids


def write_scvp(paths: list[Path], out: Path) -> ExportReport:
    """The ``scvp`` format (see the module docstring) of shards ``paths`` under ``out``; every
    shard is checked before anything is written."""
    positions = None
    for path in paths:
        with Shard(path) as shard:
            _check_scvp(shard)
            here = shard["view_positions"]
            if positions is not None and not np.array_equal(here, positions):
                raise ShardError(f"{path}: other candidate views than {paths[0]}: export shards of one view layout "
                                 "together")
            positions = here
    report = ExportReport(out)
    lines = [str(len(positions))] + [" ".join(repr(value) for value in row) for row in positions.tolist()]
    (out / "view_space.txt").write_text("\n".join(lines) + "\n")
    report.files += 1
    meshes, runs = set(), set()
    for path in paths:
        with Shard(path) as shard:
            covers, run = shard["cover"], shard["run"]
            meshes.add(mesh_folder_name(path))
            runs.update((mesh_folder_name(path), int(number)) for number in run)
            for index in range(len(shard)):
                folder = out / Path(path).stem / f"{index:06d}"
                folder.mkdir(parents=True)
                grid = shard.grids(index).reshape(-1)  # C order of [x, y, z]
                (folder / "grid.txt").write_text("\n".join(f"{value:.9g}" for value in grid.tolist()) + "\n")
                (folder / "view_ids.txt").write_text("".join(f"{view}\n" for view in np.flatnonzero(covers[index])))
                report.files += 2
            report.states += len(shard)
    report.meshes, report.runs = len(meshes), len(runs)
    return report


def _check_scvp(shard: Shard) -> None:
    """One line naming every setting a shard lacks for SCVP's format, all at once (each one
    missing costs a regeneration)."""
    lacks, fixes = [], []
    if not shard.has("cover"):
        lacks.append("no set-cover labels")
        fixes.append("--set oracle.cover=true")
    views = len(shard["view_positions"])
    if views != SCVP_VIEWS:
        lacks.append(f"{plural(views, 'candidate view')} (SCVP's format has their {SCVP_VIEWS})")
        fixes.append("--set views.layout=scvp-32 --set views.count=32")
    size = shard.file["grids"].shape[1]
    if size != SCVP_GRID:
        lacks.append(f"{size}^3 grids (SCVP reads {SCVP_GRID}^3)")
        fixes.append(f"--set grid.size={SCVP_GRID}")
    if lacks:
        raise ShardError(f"{shard.path}: {', '.join(lacks)}; generate with {' '.join(fixes)} to export --format scvp")


# --format name -> writer(shard paths, out folder) -> ExportReport
FORMATS: dict[str, Callable[[list[Path], Path], ExportReport]] = {"pc-nbv": write_pc_nbv, "scvp": write_scvp}


def describe(report: ExportReport, fmt: str) -> str:
    """The line ``nbvdata export`` prints."""
    return (f"exported {plural(report.states, 'state')} of {plural(report.runs, 'run')} and "
            f"{plural(report.meshes, 'mesh')} as {fmt} to {report.out} ({plural(report.files, 'file')})")
