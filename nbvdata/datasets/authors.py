"""Import the authors' published regression dataset (nbv-regression-2019) into standard shards.

The authors publish two arrays (``../shared/REFERENCE.md``, "The authors' regression dataset"):
``dataset_volumes_regression.npy`` (N, 32768) float64, one C-order 32^3 grid of OctoMap
probabilities per row (exactly 0.5 = unknown), and ``dataset_pose.npy`` (N, 6) float64, the NBV
of each grid as (x, y, z, yaw, pitch, roll). Either may be given as the .npy or as the zip that
holds it; a zip member is decompressed as a stream, never extracted to disk.

The importer reads the poses whole (N x 48 bytes) and the grids once, in blocks of
``BLOCK_ROWS`` rows, and writes shards of ``rows_per_shard`` rows (``legacy-00000.h5``, ...) in
the schema of ``nbvdata.schema.shards``. Memory: one block of float64 grids (32 rows = 8 MB) and about
four times that in temporaries, plus one shard's grid codes (rows_per_shard x 32 KB = 64 MB at
the default 2048): about 130 MB whatever N, never the whole 3.97 GB (the whole dataset: 15 s,
1,100 rows/s on 2 cores).

Derived, not published: ``run`` and ``step``. The rows are stored in reconstruction order and
within a run knowledge only grows, so a run ends where a voxel known in one grid (value != 0.5)
is unknown in the next. ``view_positions`` are the distinct NBV positions of the whole dataset
(the authors' candidate view set is not published); ``gains``, ``overlaps``, ``coverage``,
``mesh_id``, ``last_view``, ``seed`` and ``view_poses`` are left out rather than invented.
"""

from __future__ import annotations

import json
import time
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from numpy.lib import format as npy_format

from nbvdata import __version__
from nbvdata.core.errors import UserError
from nbvdata.core.text import plural
from nbvdata.schema.shards import PARTIAL_SUFFIX, GridPalette, Shard, ShardError, write_shard

GRID_SIZE = 32
ROW = GRID_SIZE ** 3
UNKNOWN = 0.5
BLOCK_ROWS = 32
READ_BYTES = 1 << 20
SHARD_NAME = "legacy-{:05d}.h5"
DATASET = "nbv-regression-2019 (Vasquez-Gomez et al., GPL-3.0)"
EXPECTED = {ROW: ("grids", "dataset_volumes_regression"), 6: ("poses", "dataset_pose")}  # columns: kind, file stem


class AuthorsDataError(UserError):
    """An input the importer cannot use; the one-line message names the file and the fix."""


class NpyRows:
    """A 2-D float64 C-order .npy array, plain or inside a zip, read a block of rows at a time.

    ``rows`` and ``name`` (the .npy's file name) come from the header; ``read(count)`` returns
    the next (count, columns) float64 rows. Use as a context manager.
    """

    def __init__(self, path: str | Path, columns: int):
        self.path, self.columns = Path(path), columns
        kind, stem = EXPECTED[columns]
        self._fix = f"pass the authors' {stem}.npy or the zip that holds it"
        if not self.path.is_file():
            raise AuthorsDataError(f"{self.path}: no such file: {self._fix}")
        self._zip = None
        if zipfile.is_zipfile(self.path) or self.path.suffix.lower() == ".zip":
            self._file = self._open_member()
        else:
            self.name, self.label = self.path.name, str(self.path)
            self._file = open(self.path, "rb")
        try:
            self.rows, self.dtype = self._header(kind)
        except Exception:
            self.close()
            raise
        self._done = 0

    def _open_member(self):
        """The zip's one .npy member, opened as a stream (macOS "__MACOSX/" copies are ignored)."""
        try:
            self._zip = zipfile.ZipFile(self.path)
            members = [name for name in self._zip.namelist()
                       if name.lower().endswith(".npy") and not name.startswith("__MACOSX/")]
            if len(members) != 1:
                found = ", ".join(self._zip.namelist()) or "nothing"
                raise AuthorsDataError(f"{self.path}: the zip holds {len(members) or 'no'} .npy files ({found}), "
                                  f"expected one: {self._fix}")
            self.name, self.label = Path(members[0]).name, f"{self.path}:{members[0]}"
            return self._zip.open(members[0])
        except (zipfile.BadZipFile, NotImplementedError, OSError) as error:
            if self._zip is not None:
                self._zip.close()
            raise AuthorsDataError(f"{self.path}: not a readable zip file ({error}): download it again, or pass "
                              "the unpacked .npy") from None
        except AuthorsDataError:
            self._zip.close()
            raise

    def _header(self, kind: str) -> tuple[int, np.dtype]:
        try:
            version = npy_format.read_magic(self._file)
            if version not in ((1, 0), (2, 0)):
                raise ValueError(f"npy format version {version} (this reader knows 1.0 and 2.0)")
            read = npy_format.read_array_header_1_0 if version == (1, 0) else npy_format.read_array_header_2_0
            shape, fortran_order, dtype = read(self._file)
        except (ValueError, EOFError) as error:
            raise AuthorsDataError(f"{self.label}: not a .npy array ({error}): {self._fix}") from None
        if dtype.kind != "f" or dtype.itemsize != 8 or fortran_order or len(shape) != 2 or shape[1] != self.columns:
            order = "Fortran-order" if fortran_order else "C-order"
            raise AuthorsDataError(f"{self.label}: holds a {order} {shape} {dtype} array, expected C-order float64 "
                              f"(N, {self.columns}) {kind}: {self._fix}")
        return shape[0], dtype

    def read(self, count: int) -> np.ndarray:
        """The next ``count`` rows: (count, columns) float64."""
        rows = np.empty((count, self.columns), dtype=self.dtype)
        view, filled = memoryview(rows).cast("B"), 0
        while filled < len(view):  # pieces of <= 1 MiB: the zip reader would copy a large read 5 times
            try:
                piece = self._file.read(min(len(view) - filled, READ_BYTES))
            except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as error:
                raise AuthorsDataError(f"{self.label}: corrupt data after row {self._done} ({error}): download it "
                                  "again") from None
            if not piece:
                raise AuthorsDataError(f"{self.label}: truncated: the header promises {plural(self.rows, 'row')}, the "
                                  f"data end in row {self._done + filled // (self.columns * 8)}: download or unpack "
                                  "it again")
            view[filled:filled + len(piece)] = piece
            filled += len(piece)
        self._done += count
        return rows.astype(np.float64, copy=False)

    def close(self) -> None:
        self._file.close()
        if self._zip is not None:
            self._zip.close()

    def __enter__(self) -> "NpyRows":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def distinct_views(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) NBV positions -> the distinct ones (V, 3), sorted, and each row's index (N,) int32.

    Positions equal after rounding to 1e-6 m are one view; it keeps its first row's exact value.
    """
    keys = np.round(positions, 6) + 0.0  # + 0.0 turns -0.0 into 0.0
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    return positions[first], inverse.reshape(-1).astype(np.int32)


class RunSplitter:
    """Run and step numbers of grids in reconstruction order, fed one block at a time.

    A new run starts at grid i+1 when a voxel known in grid i is unknown in grid i+1.
    ``lengths`` lists the steps of every run seen so far (the last one maybe unfinished).
    """

    def __init__(self):
        self._known: np.ndarray | None = None  # (ROW,) bool, known voxels of the last grid
        self._run, self._step = -1, 0
        self._finished: list[int] = []

    def update(self, grids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, ROW) grids -> run (n,) int32 (0-based, global), step (n,) int32 (1-based)."""
        known = grids != UNKNOWN
        starts = np.empty(len(known), dtype=bool)
        starts[0] = self._known is None or bool((self._known & ~known[0]).any())
        starts[1:] = (known[:-1] & ~known[1:]).any(axis=1)
        index = np.arange(len(known))
        last_start = np.maximum.accumulate(np.where(starts, index, -1))
        step = np.where(last_start >= 0, index - last_start + 1, self._step + index + 1)
        before = np.concatenate([[self._step], step[:-1]])[starts]  # steps of the runs that end here
        self._finished += before[before > 0].tolist()
        run = self._run + np.cumsum(starts)
        self._known, self._run, self._step = known[-1].copy(), int(run[-1]), int(step[-1])
        return run.astype(np.int32), step.astype(np.int32)

    @property
    def lengths(self) -> list[int]:
        return self._finished + ([self._step] if self._step else [])


class BlockEncoder:
    """``GridPalette(log_odds=False)`` codes of blocks of grids, by a sorted look-up of the values
    seen so far (20x faster than ``GridPalette.encode`` on a block; the same palette)."""

    def __init__(self):
        self.palette = GridPalette(log_odds=False)
        self._values = np.array([UNKNOWN])
        self._codes = self.palette.encode(self._values)

    def encode(self, grids: np.ndarray) -> np.ndarray:
        """(n, ROW) float64 -> (n, ROW) uint16 codes; ``palette.probabilities()[codes]`` is ``grids``
        as float32."""
        index = np.minimum(np.searchsorted(self._values, grids), len(self._values) - 1)
        new = self._values[index] != grids
        if new.any():
            self._values = np.union1d(self._values, grids[new])
            self._codes = self.palette.encode(self._values)
            index = np.searchsorted(self._values, grids)
        return self._codes[index]


@dataclass
class ImportReport:
    """The outcome of one ``import_legacy`` call; ``run_lengths`` are the steps of every run."""

    out_dir: Path
    rows: int = 0
    written: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    run_lengths: list[int] = field(default_factory=list)
    seconds: float = 0.0


def _config(views: np.ndarray) -> str:
    """The shards' ``config`` attribute: what is known of the data's settings."""
    radius = float(np.round(np.median(np.linalg.norm(views, axis=1)), 6))
    return yaml.safe_dump({
        "grid": {"size": GRID_SIZE},
        "views": {"count": len(views), "radius": radius,
                  "positions": "the distinct NBV positions of the whole dataset (view_positions)"},
        "note": f"imported by nbvdata import-legacy from {DATASET}: grids are OctoMap probabilities "
                "(0.5 = unknown); run and step are derived from the row order; the grid extent and "
                "the candidate views of the authors' simulation are not part of the dataset",
    }, sort_keys=False)


def _complete(path: Path, source: str) -> bool:
    """True when ``path`` is a readable shard of ``source``; a broken one is written again."""
    if not path.exists():
        return False
    try:
        with Shard(path) as shard:
            found = shard.info.source
    except ShardError:
        return False
    if found != source:
        raise AuthorsDataError(f"{path}: holds {found!r}, this import writes {source!r}: use a new --out folder "
                          "or delete the old shards")
    return True


def _assemble(codes: np.ndarray, palette: GridPalette, run: np.ndarray, step: np.ndarray, poses: np.ndarray,
              nbv_index: np.ndarray, views: np.ndarray) -> dict[str, np.ndarray]:
    """A shard's arrays from its (n, ROW) codes, (n,) run, step and nbv_index, (n, 6) poses and
    the (V, 3) views."""
    positions = poses[:, :3]
    return {
        "grids": codes.reshape(-1, GRID_SIZE, GRID_SIZE, GRID_SIZE),
        "grid_palette": palette.probabilities(),
        "nbv_index": nbv_index,
        "nbv_pose": poses,
        "nbv_position": (positions / np.linalg.norm(positions, axis=1, keepdims=True)).astype(np.float32),
        "run": run,
        "step": step,
        "view_positions": views,
    }


def import_legacy(volumes: str | Path, poses: str | Path, out_dir: str | Path, rows_per_shard: int = 2048,
                  limit: int | None = None, show_progress: bool | None = None) -> ImportReport:
    """Import the first ``limit`` (default all) rows into ``out_dir``, skipping complete shards.

    ``volumes``, ``poses``: the authors' .npy files or their zips. ``show_progress`` None shows
    the bar only on a terminal.
    """
    from tqdm import tqdm

    start = time.perf_counter()
    out_dir = Path(out_dir)
    report = ImportReport(out_dir)
    with NpyRows(poses, 6) as stream:
        pose_rows = stream.read(stream.rows)
    with NpyRows(volumes, ROW) as grids:
        if grids.rows != len(pose_rows):
            raise AuthorsDataError(f"{grids.label} holds {plural(grids.rows, 'grid')} but {Path(poses)} holds "
                              f"{plural(len(pose_rows), 'pose')}: pass the volumes and poses of the same dataset")
        total = grids.rows if limit is None else min(limit, grids.rows)
        views, nbv_index = distinct_views(pose_rows[:, :3])
        config = _config(views)
        out_dir.mkdir(parents=True, exist_ok=True)
        for stale in out_dir.glob(f"legacy-*{PARTIAL_SUFFIX}"):
            stale.unlink()  # left by a killed import
        splitter = RunSplitter()
        buffer = np.empty((min(rows_per_shard, total), ROW), dtype=np.uint8)  # one shard's codes
        bar = tqdm(total=total, unit="row", desc="import-legacy", dynamic_ncols=True,
                   disable=None if show_progress is None else not show_progress)
        try:
            for number, first in enumerate(range(0, total, rows_per_shard)):
                stop = min(first + rows_per_shard, total)
                path = out_dir / SHARD_NAME.format(number)
                source = f"legacy: {DATASET} {grids.name} rows {first}-{stop}"
                done = _complete(path, source)
                if not done:
                    encoder, codes = BlockEncoder(), buffer[:stop - first]
                run, step = np.empty(stop - first, dtype=np.int32), np.empty(stop - first, dtype=np.int32)
                for at in range(first, stop, BLOCK_ROWS):
                    block = grids.read(min(BLOCK_ROWS, stop - at))
                    rows = slice(at - first, at - first + len(block))
                    run[rows], step[rows] = splitter.update(block)
                    if not done:
                        block_codes = encoder.encode(block)
                        if len(encoder.palette) > 256 and codes.dtype == np.uint8:
                            codes = codes.astype(np.uint16)
                        codes[rows] = block_codes
                    report.rows += len(block)
                    bar.update(len(block))
                if done:
                    report.skipped.append(path.name)
                    continue
                arrays = _assemble(codes, encoder.palette, run, step, pose_rows[first:stop],
                                   nbv_index[first:stop], views)
                attrs = {
                    "package_version": __version__,
                    "config": config,
                    "meshes": json.dumps([], allow_nan=False),
                    "samples": stop - first,
                    "runs": np.array([run[0], run[-1] + 1], dtype=np.int64),
                    "source": source,
                    "rows": np.array([first, stop], dtype=np.int64),
                }
                write_shard(path, arrays, attrs)
                report.written.append(path.name)
        finally:
            bar.close()
            report.run_lengths = splitter.lengths
            report.seconds = time.perf_counter() - start
    return report
