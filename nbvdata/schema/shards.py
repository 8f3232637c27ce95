"""HDF5 shards of labelled reconstruction states: the dataset's file format.

Schema version 1. A shard holds the samples of one work unit (one mesh, a range of runs).
N samples, V candidate views, n = ``grid.size``. Per-sample arrays are chunked one sample per
chunk and gzip-compressed (level 4); every dataset is written without timestamps, so the same
data gives the same bytes.

Integrity (shards written by nbvdata 0.1.0 from issue 50 on; ``INTEGRITY``): every chunk of every
dataset carries HDF5's Fletcher-32 checksum (the per-shard arrays are one chunk each), which
HDF5 checks at every read, and the ``attributes_sha256`` attribute is the sha256 of the other
attributes (``attributes_digest``), checked when a shard is opened. Every read also checks the
values that have a range (``VALUE_RULES``: probabilities and fractions in [0, 1], finite
coordinates, view indices among the views, palette codes within the palette), so a shard from
before the checksums, or one damaged in a way no checksum sees, fails in one line too.
``Shard.check`` reads everything: what ``nbvdata verify`` and a resumed ``generate`` run.

Datasets::

    grids          (N, n, n, n) uint8    palette codes (uint16 if a shard has > 256 distinct values);
                                         grid_palette[grids] is the occupancy grid
    grid_palette   (K,) float32          probability of each code, the authors' encoding (OctoMap
                                         probabilities, exact: code 0 is 0.5 = unknown)
    nbv_index      (N,) int32            ground-truth next-best-view, a row of view_positions
    nbv_pose       (N, 6) float64        that view as x, y, z (m), yaw, pitch, roll (rad), the authors'
                                         convention (R = Rz @ Ry @ Rx, world to camera)
    nbv_position   (N, 3) float32        that view's position / radius: the unit vector networks regress
    gains          (N, V) float32        every view's gain: observable coverage it would add
    overlaps       (N, V) float32        every view's overlap: covered fraction of what it would see
    coverage       (N, 2) float32        observable coverage of the state, and after scanning the NBV
    mesh_id        (N,) S64              mesh id (sha256 hex), described in the ``meshes`` attribute
    run            (N,) int32            run number within the mesh
    step           (N,) int32            scans taken in the state (1 = just the start view)
    last_view      (N,) int32            the view scanned last (the start view when step = 1)
    seed           (N,) int64            the run's seed (its range noise, if any)
    view_positions (V, 3) float64        candidate view positions, metres
    view_poses     (V, 6) float64        candidate view poses (x, y, z, yaw, pitch, roll)
    move           (N,) int8             how the run left the state: 0 to the NBV (oracle), 1 to a random
                                         valid view (explore), 2 where the policy chose (policy), -1 not
                                         at all (the run ended there); only in runs off the oracle's path
    next_view      (N,) int32            the view scanned next (-1: none, or a pose that is no candidate
                                         view); only in runs off the oracle's path
    next_pose      (N, 6) float64        the pose scanned next, as nbv_pose (NaN: none); only in runs
                                         off the oracle's path
    cover          (N, V) bool           the fewest views whose scans cover all the observable reference
                                         points the state has not covered (SCVP's set-cover label; the
                                         best set found when not proved optimal); only with oracle.cover
    cover_size     (N,) int16            views in cover; only with oracle.cover
    cover_bound    (N,) int16            proven lower bound on the fewest views (== cover_size when proved
                                         optimal); only with oracle.cover
    cover_greedy   (N,) int16            views in the greedy set cover (most new points first); only with
                                         oracle.cover
    points         (N, P, 3) float32     the state's partial cloud, object frame, metres: every point its
                                         run scanned so far (range noise included) reduced to P =
                                         state.points by farthest-point sampling from the first
                                         (nbvdata.core.cloud), repeated from the first when fewer; only with
                                         state.points > 0
    points_count   (N,) int32            how many points were scanned before reduction (when at most P,
                                         the first points_count rows are all of them, in scan order);
                                         only with state.points > 0
    reference_points (R, 3) float32      the mesh's coverage reference points (coverage.points of them,
                                         on the surface): PC-NBV's ground-truth cloud; only with
                                         state.points > 0
    surface        (n, n, n) bool        the voxels of the scene grid the mesh's surface passes through
                                         (``nbvdata.simulation.scene.Scene.surface_voxels``), indexed as ``grids``:
                                         where a scan could mark a voxel occupied; once per shard, only
                                         with state.surface

Optional datasets (``OPTIONAL``): ``gains``, ``overlaps``, ``coverage``, ``mesh_id``,
``last_view``, ``seed`` and ``view_poses`` may be absent: a shard imported from a dataset that
did not publish them (``nbvdata import-legacy``) leaves them out rather than inventing values.
``nbvdata generate`` always writes all of them (a generated shard without one is incomplete).
``Shard.has(name)`` tells.

Runs off the oracle's path (``MOVES``): when a run always moves to the NBV, ``last_view`` of the
next state is the label and nothing more needs recording; such shards (``episode.explore`` 0,
no ``--policy``) hold no ``move``, ``next_view`` or ``next_pose``, byte for byte the shards of
before these datasets existed. A generated shard whose runs explore (its ``config`` has
``episode.explore`` > 0) or follow a policy (it has the ``policy`` attribute) holds all three.
There ``nbv_index`` is still the exact label of every state, but the next state follows
``next_view``/``next_pose``; ``last_view`` is -1 after a pose that is no candidate view (that
pose is the previous sample's ``next_pose``), and ``coverage[:, 1]`` is still what the NBV
would have reached. New datasets that old readers ignore: the schema version stays 1.

Set-cover labels (``COVER``, ``nbvdata.simulation.setcover``): a generated shard whose ``config`` has
``oracle.cover`` true holds ``cover``, ``cover_size``, ``cover_bound`` and ``cover_greedy``;
others hold none of them (byte for byte the shards of before). Views already scanned count as
given and the overlap rule is no part of the cover, as in SCVP.

Point clouds (``CLOUDS``): a shard made with ``state.points`` > 0 holds ``points``,
``points_count`` and ``reference_points``; with the default 0 none of them, byte for byte the
shards of before they existed (the ``config`` attribute leaves ``state`` out at its default).

The surface (``SURFACE``): a shard made with ``state.surface`` holds ``surface``; others do not.

Attributes: ``schema_version`` (int), ``package_version``, ``config`` (YAML of the settings that
determine the data), ``meshes`` (JSON list of {"id", "source", "sha256"}; the source is the file
name, or its path under ``--meshes`` where another mesh of the job has the same stem:
``nbvdata.simulation.sources.MeshSource.recorded``), ``samples`` (N),
``runs`` ([first, stop) run numbers of the unit), ``source`` ("nbvdata generate", or what was
imported; absent in the first shards written, which mean "nbvdata generate"), ``policy`` (JSON
{"sha256", "network"} of the checkpoint the runs followed; only with ``--policy``).

A shard is written under a temporary name and renamed when complete: it is whole or absent.
A shard damaged later (bytes overwritten or cut off) is read only through ``Shard``, whose every
read turns HDF5's failure - a checksum, a gzip stream, an address - and every value out of its
range into one ``ShardError`` naming the file and the fix (``reading``).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import yaml

from nbvdata.core.errors import UserError
from nbvdata.core.logodds import probability
from nbvdata.core.text import plural
from nbvdata.core.userarrays import file_kind, is_hdf5

SCHEMA_VERSION = 1
PARTIAL_SUFFIX = ".partial"

PER_SAMPLE = {  # name: (dtype, trailing shape given V and n)
    "grids": (None, lambda v, n: (n, n, n)),
    "nbv_index": (np.int32, lambda v, n: ()),
    "nbv_pose": (np.float64, lambda v, n: (6,)),
    "nbv_position": (np.float32, lambda v, n: (3,)),
    "gains": (np.float32, lambda v, n: (v,)),
    "overlaps": (np.float32, lambda v, n: (v,)),
    "coverage": (np.float32, lambda v, n: (2,)),
    "mesh_id": ("S64", lambda v, n: ()),
    "run": (np.int32, lambda v, n: ()),
    "step": (np.int32, lambda v, n: ()),
    "last_view": (np.int32, lambda v, n: ()),
    "seed": (np.int64, lambda v, n: ()),
    "move": (np.int8, lambda v, n: ()),
    "next_view": (np.int32, lambda v, n: ()),
    "next_pose": (np.float64, lambda v, n: (6,)),
    "cover": (bool, lambda v, n: (v,)),
    "cover_size": (np.int16, lambda v, n: ()),
    "cover_bound": (np.int16, lambda v, n: ()),
    "cover_greedy": (np.int16, lambda v, n: ()),
    "points": (np.float32, lambda v, n, p=1: (p, 3)),
    "points_count": (np.int32, lambda v, n: ()),
}
PER_SHARD = ("grid_palette", "view_positions", "view_poses", "reference_points", "surface")
GENERATED = "nbvdata generate"  # the ``source`` attribute of generated shards: nothing optional
OPTIONAL = frozenset({"gains", "overlaps", "coverage", "mesh_id", "last_view", "seed", "view_poses"})
MOVES = frozenset({"move", "next_view", "next_pose"})  # only in runs off the oracle's path
MOVE_RULES = ("oracle", "explore", "policy")  # what the ``move`` codes 0, 1, 2 mean
COVER = frozenset({"cover", "cover_size", "cover_bound", "cover_greedy"})  # only with oracle.cover
CLOUDS = frozenset({"points", "points_count", "reference_points"})  # only with state.points > 0
SURFACE = frozenset({"surface"})  # only with state.surface
ATTRIBUTES_DIGEST = "attributes_sha256"  # the attribute that checks the others (module docstring)

# What the values of a dataset must be (module docstring): "probability" and "fraction" in [0, 1],
# "finite" no NaN or infinity, "view" an index of view_positions (-1 allowed: "view or none"),
# "code" an index of grid_palette.
VALUE_RULES = {"grid_palette": "probability", "gains": "fraction", "overlaps": "fraction", "coverage": "fraction",
               "nbv_pose": "finite", "nbv_position": "finite", "view_positions": "finite", "view_poses": "finite",
               "points": "finite", "reference_points": "finite", "nbv_index": "view", "last_view": "view or none",
               "next_view": "view or none", "grids": "code"}


class ShardError(UserError):
    """A shard that cannot be read; the message names the file and the fix."""


@contextlib.contextmanager
def reading(path: Path, what: str = "its data"):
    """Reads of shard ``path`` inside the block: HDF5's failure to read bytes that were overwritten
    or cut off (OSError: a chunk whose Fletcher-32 checksum or gzip/zlib stream fails, an address
    beyond the end of the file; RuntimeError on some metadata) becomes one ``ShardError`` naming the
    shard, ``what`` could not be read, and the fix."""
    try:
        yield
    except (OSError, RuntimeError) as error:
        reason = (str(error).strip().splitlines() or [type(error).__name__])[0][:100]
        raise damaged(path, f"{what} cannot be read (HDF5: {reason})") from None


def damaged(path: Path, what: str) -> ShardError:
    """The one-line error of a shard whose bytes were damaged: ``what`` is wrong, and the fix."""
    return ShardError(f"{path}: damaged, {what}: delete it and run nbvdata generate again, or restore it from its "
                      "published version (nbvdata verify names every damaged shard)")


def attributes_digest(attrs) -> str:
    """sha256 (hex) of a shard's attributes but ``ATTRIBUTES_DIGEST`` itself, by name, each value
    as plain data (what was written and what h5py reads back give the same text)."""
    def plain(value):
        if isinstance(value, np.ndarray):
            return value.tolist()
        if isinstance(value, np.generic):
            return value.item()
        return value.decode() if isinstance(value, bytes) else value
    values = {key: plain(attrs[key]) for key in sorted(attrs) if key != ATTRIBUTES_DIGEST}
    return hashlib.sha256(json.dumps(values, sort_keys=True, allow_nan=False).encode()).hexdigest()


def value_problem(name: str, values: np.ndarray, views: int, codes: int) -> str | None:
    """What is wrong with ``values`` read from dataset ``name`` (``VALUE_RULES``; ``views`` V,
    ``codes`` the palette's length), or None."""
    rule = VALUE_RULES.get(name)
    values = np.asarray(values)
    if rule is None or values.size == 0:
        return None
    if rule in ("probability", "fraction", "finite"):
        if not np.isfinite(values).all():
            return f"{np.count_nonzero(~np.isfinite(values)):,} values are not finite (NaN or infinity)"
        if rule != "finite" and not (values.min() >= 0 and values.max() <= 1):
            return f"values {values.min():g}..{values.max():g} are not all in [0, 1]"
        return None
    low, high = (-1 if rule == "view or none" else 0), (codes if rule == "code" else views) - 1
    if values.min() < low or values.max() > high:
        what = "palette codes" if rule == "code" else "view indices"
        return f"{what} {values.min()}..{values.max()} are not all in {low}..{high}"
    return None


class GridPalette:
    """The distinct values of a shard's grids, coded in order of first appearance.

    By default the values are float32 log-odds (code 0 = 0.0, never observed); with
    ``log_odds=False`` they are probabilities already (code 0 = 0.5, unknown), as in the
    authors' files.
    """

    def __init__(self, log_odds: bool = True):
        self._is_log_odds = log_odds
        unknown = 0.0 if log_odds else 0.5
        self._log_odds: list[float] = [unknown]  # code 0: never observed, probability 0.5
        # The known values in ascending order and their codes, for a binary search per voxel.
        self._sorted = np.array([unknown], dtype=np.float64)
        self._sorted_codes = np.array([0], dtype=np.uint16)

    def __len__(self) -> int:
        return len(self._log_odds)

    def encode(self, log_odds: np.ndarray) -> np.ndarray:
        """(...) grid values -> (...) uint16 codes; values not seen before get new codes, in
        ascending order of value."""
        values = np.asarray(log_odds, dtype=np.float64)
        slots = self._lookup(values)
        known = self._sorted[slots] == values
        if not known.all():
            new = np.unique(values[~known])
            if len(self._log_odds) + len(new) > np.iinfo(np.uint16).max + 1:
                raise ValueError("more than 65,536 distinct grid values in one shard")
            codes = np.arange(len(self._log_odds), len(self._log_odds) + len(new), dtype=np.uint16)
            self._log_odds += new.tolist()
            values_known = np.concatenate([self._sorted, new])
            order = np.argsort(values_known)
            self._sorted = values_known[order]
            self._sorted_codes = np.concatenate([self._sorted_codes, codes])[order]
            slots = self._lookup(values)
        return self._sorted_codes[slots]

    def _lookup(self, values: np.ndarray) -> np.ndarray:
        """Index into the sorted known values of each of ``values`` (where it is, if known)."""
        return np.minimum(np.searchsorted(self._sorted, values), len(self._sorted) - 1)

    def probabilities(self) -> np.ndarray:
        """(K,) float32 probability of each code, as ``OccupancyGrid.probabilities``."""
        if not self._is_log_odds:
            return np.array(self._log_odds, dtype=np.float32)
        return probability(np.array(self._log_odds, dtype=np.float32))


def write_shard(path: Path, arrays: dict[str, np.ndarray], attrs: dict, partial: Path | None = None) -> None:
    """Write a complete shard atomically: to ``partial`` (default ``path + .partial``), then
    rename over ``path``.

    ``arrays`` holds every dataset of the schema (the ``OPTIONAL``, ``MOVES``, ``COVER``, ``CLOUDS`` and
    ``SURFACE`` ones may be left out); ``attrs`` every attribute but the version and the attributes' digest.
    Every chunk gets a Fletcher-32 checksum (module docstring).
    """
    path = Path(path)
    missing = sorted((set(PER_SAMPLE) | set(PER_SHARD)) - set(arrays) - OPTIONAL - MOVES - COVER - CLOUDS - SURFACE)
    if missing:
        raise ValueError(f"write_shard: missing arrays {missing}")
    count = len(arrays["nbv_index"])
    partial = Path(partial) if partial is not None else path.with_name(path.name + PARTIAL_SUFFIX)
    try:
        with h5py.File(partial, "w", libver=("earliest", "v110")) as f:
            f.attrs["schema_version"] = SCHEMA_VERSION
            for key, value in attrs.items():
                f.attrs[key] = value
            f.attrs[ATTRIBUTES_DIGEST] = attributes_digest(f.attrs)
            for name in PER_SHARD:
                if name in arrays:
                    data = np.asarray(arrays[name])
                    packed = {"compression": "gzip", "compression_opts": 4} if name in SURFACE else {}
                    _written(f.create_dataset(name, data=data, chunks=data.shape if data.size else None,
                                              fletcher32=bool(data.size), track_times=False, **packed))
            for name in PER_SAMPLE:
                if name not in arrays:
                    continue
                data = np.asarray(arrays[name])
                if len(data) != count:
                    raise ValueError(f"write_shard: {name} has {len(data)} rows, nbv_index has {count}")
                chunks = (1,) + data.shape[1:] if count and data.ndim > 1 else None
                _written(f.create_dataset(name, data=data, chunks=chunks if count else None,
                                          compression="gzip" if count else None,
                                          compression_opts=4 if count else None, fletcher32=bool(count),
                                          track_times=False))
            f.flush()
            os.fsync(f.id.get_vfd_handle())
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    os.replace(partial, path)


def _written(dataset: h5py.Dataset) -> None:
    """Put ``dataset``'s chunks in the file now. HDF5 gives a chunk its place in the file when
    the chunk leaves the dataset's cache - when the dataset is closed, i.e. when the last Python
    reference to it goes - so a reference held a moment longer (a profiler sampling the writing
    thread's frames, as a Dask worker's does; a debugger) moved the chunks after the next
    datasets': the same content in other bytes. Flushed here, the layout is the order of the
    writes, whoever else holds the object."""
    dataset.flush()


@dataclass(frozen=True)
class ShardInfo:
    """What a shard's attributes say."""

    path: Path
    samples: int
    config: dict
    meshes: list[dict]
    runs: tuple[int, int]
    package_version: str
    source: str


class Shard:
    """A shard opened for reading: ``len``, ``info``, ``grids(index)``, ``codes(index)``,
    ``read(name, index)`` and ``[name]`` for any dataset; every read goes through ``reading``.

    Use as a context manager, or call ``close``.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_file():
            raise ShardError(f"{self.path}: no such shard")
        try:
            self.file = h5py.File(self.path, "r")
        except OSError:
            if not is_hdf5(self.path):  # no shard at all: nothing to delete or regenerate
                raise ShardError(f"{self.path}: not an HDF5 file ({file_kind(self.path)}), so not a shard: give the "
                                 ".h5 files nbvdata generate (or import-legacy) wrote") from None
            raise ShardError(f"{self.path}: not a readable HDF5 file (truncated or corrupt?): "
                             "delete it and run nbvdata generate again") from None
        try:
            with reading(self.path, "its attributes"):
                self.info = self._check()
        except (yaml.YAMLError, json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError) as error:
            self.file.close()
            raise damaged(self.path, f"its attributes cannot be read ({type(error).__name__})") from None
        except Exception:
            self.file.close()
            raise

    def _check(self) -> ShardInfo:
        attrs = self.file.attrs
        version = attrs.get("schema_version")
        if version is None:
            raise ShardError(f"{self.path}: not an nbvdata shard (no schema_version attribute)")
        if int(version) != SCHEMA_VERSION:
            raise ShardError(f"{self.path}: schema version {int(version)}, this nbvdata reads "
                             f"{SCHEMA_VERSION}: regenerate the shard or install a matching nbvdata")
        if ATTRIBUTES_DIGEST in attrs and attrs[ATTRIBUTES_DIGEST] != attributes_digest(attrs):
            raise damaged(self.path, "its attributes do not match their checksum")
        source = str(attrs.get("source", GENERATED))
        config = yaml.safe_load(attrs["config"])
        optional = OPTIONAL if source != GENERATED else frozenset()
        if not off_oracle_path(config, attrs):
            optional |= MOVES
        if not has_covers(config):
            optional |= COVER
        if not cloud_points(config):
            optional |= CLOUDS
        if not has_surface(config):
            optional |= SURFACE
        missing = [name for name in (*PER_SAMPLE, *PER_SHARD) if name not in self.file and name not in optional]
        if missing:
            raise ShardError(f"{self.path}: incomplete shard, missing {', '.join(missing)}: "
                             "delete it and run nbvdata generate again")
        samples = int(attrs["samples"])
        wrong = [name for name in PER_SAMPLE if name in self.file and len(self.file[name]) != samples]
        if wrong:
            raise ShardError(f"{self.path}: {', '.join(wrong)} do not hold {plural(samples, 'sample')}: "
                             "delete it and run nbvdata generate again")
        self._views = self.file["view_positions"].shape[0]
        self._codes = self.file["grid_palette"].shape[0]
        return ShardInfo(self.path, samples, config, json.loads(attrs["meshes"]),
                         tuple(int(r) for r in attrs["runs"]), str(attrs["package_version"]),
                         source)

    def check(self) -> None:
        """Read every dataset whole - each chunk's checksum and gzip stream, every value's range
        (``VALUE_RULES``): ShardError naming the first damage, else nothing."""
        for name in self.file:
            self.read(name)

    def __len__(self) -> int:
        return self.info.samples

    def has(self, name: str) -> bool:
        """Whether the shard holds dataset ``name`` (the ``OPTIONAL`` ones may be absent)."""
        return name in self.file

    def __getitem__(self, name: str) -> np.ndarray:
        """The whole dataset ``name`` as an array (grids as palette codes; see ``grids``)."""
        return self.read(name)

    def read(self, name: str, index: int | slice | np.ndarray | tuple = ()) -> np.ndarray:
        """Rows ``index`` of dataset ``name`` (default all; an index array must increase), the
        one way shard data is read: ShardError naming the shard when its bytes are damaged or its
        values leave their range (``VALUE_RULES``)."""
        with reading(self.path, f"dataset {name}"):
            values = self.file[name][index]
        problem = value_problem(name, values, self._views, self._codes)
        if problem is not None:
            raise damaged(self.path, f"dataset {name}: {problem}")
        return values

    def cloud(self, index: int) -> np.ndarray:
        """(n, 3) float32: the points sample ``index``'s run had scanned - all of them when there
        were at most ``state.points`` (``points_count``; none when nothing was scanned), else the
        ``state.points`` farthest-point sampling kept."""
        points = self.read("points", index)
        return points[:min(int(self.read("points_count", index)), len(points))]

    @property
    def palette(self) -> np.ndarray:
        return self.read("grid_palette")

    def codes(self, index: int | slice | np.ndarray = slice(None)) -> np.ndarray:
        """(..., n, n, n) palette codes of the selected samples (``palette[codes]`` are the grids)."""
        return self.read("grids", index)

    def grids(self, index: int | slice | np.ndarray = slice(None)) -> np.ndarray:
        """(..., n, n, n) float32 occupancy probabilities of the selected samples."""
        return self.palette[self.codes(index)]

    def content_digests(self) -> dict[str, str]:
        """sha256 (first 16 hex digits) of every dataset's values - raw C-order bytes with dtype
        and shape - and of the attributes but ``package_version`` and the attributes' own checksum,
        by name: equal digests mean equal content, whatever HDF5 library, chunking, compression or
        checksums wrote the file (a shard with checksums has the content of one without)."""
        digests = {}
        for name in sorted(self.file):
            data = np.ascontiguousarray(self.read(name))
            digest = hashlib.sha256(f"{data.dtype.str}{data.shape}".encode())
            digest.update(data.tobytes())
            digests[name] = digest.hexdigest()[:16]
        attrs = {key: (value.tolist() if isinstance(value, np.ndarray) else value)
                 for key, value in sorted(self.file.attrs.items())
                 if key not in ("package_version", ATTRIBUTES_DIGEST)}
        digests["attributes"] = hashlib.sha256(repr(attrs).encode()).hexdigest()[:16]
        return digests

    def close(self) -> None:
        self.file.close()

    def __enter__(self) -> "Shard":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def off_oracle_path(config: dict, attrs) -> bool:
    """Whether a shard's runs left the oracle's path (they explore or follow a policy), from its
    ``config`` and attributes: then it holds the ``MOVES`` datasets."""
    episode = config.get("episode", {}) if isinstance(config, dict) else {}
    return episode.get("explore", 0.0) > 0 or "policy" in attrs


def has_covers(config: dict) -> bool:
    """Whether a shard's settings (its ``config``) asked for set-cover labels: then it holds ``COVER``."""
    oracle = config.get("oracle", {}) if isinstance(config, dict) else {}
    return bool(oracle.get("cover", False))


def has_surface(config: dict) -> bool:
    """Whether a shard's settings (its ``config``) asked for the mesh's surface voxels: then it holds ``SURFACE``."""
    state = config.get("state", {}) if isinstance(config, dict) else {}
    return bool(state.get("surface", False)) if isinstance(state, dict) else False


def cloud_points(config: dict) -> int:
    """Points per state's cloud of a shard, from its ``config`` (``state.points``; 0: no clouds)."""
    state = config.get("state", {}) if isinstance(config, dict) else {}
    return int(state.get("points", 0)) if isinstance(state, dict) else 0


def shard_files(items: list[Path]) -> list[Path]:
    """Shard files from file and folder arguments (a folder contributes its *.h5, sorted)."""
    paths = []
    for item in map(Path, items):
        if item.is_dir():
            found = sorted(item.glob("*.h5"))
            if not found:
                raise ShardError(f"{item}: no .h5 shards in this folder; run nbvdata generate --out {item}")
            paths += found
        elif item.exists():
            paths.append(item)
        else:
            raise ShardError(f"{item}: no such shard or folder")
    return paths


def view_state(run: np.ndarray, step: np.ndarray, last_view: np.ndarray, views: int) -> np.ndarray:
    """(N, V) bool: the candidate views each state has scanned.

    run : (N,) a key per run (its states share it); step : (N,) int scans taken (1 = the start
    view only); last_view : (N,) int the view scanned last. A run records its states at steps
    1, 2, ... S and each state's last view is the one scanned to reach it, so the views scanned
    by a state are the last views of its run's states up to its step. ValueError when a run's
    steps are not 1..S (a state missing: its views are unknown) or a view is out of range.
    """
    run, step, last_view = np.asarray(run), np.asarray(step), np.asarray(last_view)
    if len(last_view) and last_view.min() < 0:
        raise ValueError("last_view -1: states reached through a pose that is no candidate view (a regression or "
                         "classification --policy rollout), whose view state is unknown; train score networks on "
                         "other shards")
    if len(last_view) and not 0 <= last_view.min() <= last_view.max() < views:
        raise ValueError(f"last_view holds views {last_view.min()}..{last_view.max()}, outside 0..{views - 1}")
    taken = np.zeros((len(run), views), dtype=bool)
    order = np.lexsort((step, run))
    starts = np.flatnonzero(np.r_[True, run[order][1:] != run[order][:-1]])
    for rows in np.split(order, starts[1:]) if len(order) else []:
        if not np.array_equal(step[rows], np.arange(1, len(rows) + 1)):
            raise ValueError(f"run {run[rows[0]]} has states at steps {step[rows].tolist()}, not 1..{len(rows)}: "
                             "the views before a missing state are unknown")
        scanned = np.zeros((len(rows), views), dtype=bool)
        scanned[np.arange(len(rows)), last_view[rows]] = True
        taken[rows] = np.logical_or.accumulate(scanned, axis=0)
    return taken
