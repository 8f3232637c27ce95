"""Ranking data from shards: every state's candidate views as rows of per-view features
(``nbvdata.viewfeatures``), each with the exact gain the shard holds for it.

A state is one query; its rows are the candidate views it has not scanned (a scanned view is
marked by the run's ``last_view`` history, ``nbvdata.shards.view_state``). ``sample`` > 0 keeps
at most that many rows per state - its ``sample // 4`` views of largest valid gain plus gain, and a seeded
random choice of the rest (the seed derives from ``seed``, the mesh id, the run and the step,
so the rows do not depend on the number of workers) - for training; 0 keeps every row, for
validation (the gain ratio of a choice needs every view).

Two labels per row: its gain (the observable coverage it would add) and its *valid* gain, the
gain when the view's overlap passes the shard's ``oracle.min_overlap``, else 0 (the ground
truth's rule: the next-best-view is the valid view with the largest gain). ``RankingData.gains``
holds one of them (``target``: "valid" or "all"), ``RankingData.labelled`` gives the other.
"""

from __future__ import annotations

import dataclasses
import hashlib
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nbvdata.config import ConfigError, SimConfig, from_dict
from nbvdata.files import sha256_file
from nbvdata.shards import Shard, ShardError, view_state
from nbvdata.views import ViewSet, farthest_view, look_at_rotations
from nbvdata.viewfeatures import BUNDLE, FEATURES, RayBundle, view_features

_BUNDLES: dict[tuple, RayBundle] = {}


@dataclass
class RankingData:
    """Rows grouped by state, states in order.

    features : (M, F) float32, the columns ``nbvdata.viewfeatures.FEATURES``
    gains : (M,) float32 each row's label: its valid gain or its gain (``target``, module docstring)
    other : (M,) float32 the other label
    views : (M,) int32 each row's candidate view index in its state's view set
    sizes : (S,) int64 rows per state
    best, best_other : (S,) float32 the state's largest label (and other label) over all its unscanned views
    mean, mean_other : (S,) float32 the state's mean label (and other label) over all its unscanned views
    farthest, farthest_other : (S,) float32 the label (and other label) of ``farthest``'s choice at the state
    target : (S,) str "valid" or "all", what ``gains`` holds
    steps : (S,) int32 scans taken; mesh_ids : (S,) str; layouts : (S,) str ("hemisphere-500", ...)
    coverage : (S,) float32 the state's observable coverage
    """

    features: np.ndarray
    gains: np.ndarray
    other: np.ndarray
    views: np.ndarray
    sizes: np.ndarray
    best: np.ndarray
    best_other: np.ndarray
    mean: np.ndarray
    mean_other: np.ndarray
    farthest: np.ndarray
    farthest_other: np.ndarray
    target: np.ndarray
    steps: np.ndarray
    mesh_ids: np.ndarray
    layouts: np.ndarray
    coverage: np.ndarray

    def __len__(self) -> int:
        return len(self.sizes)

    @property
    def starts(self) -> np.ndarray:
        """(S,) int64 the first row of each state."""
        return np.concatenate([[0], np.cumsum(self.sizes)[:-1]]).astype(np.int64)

    def choices(self, scores: np.ndarray) -> np.ndarray:
        """(S,) int64 the row of each state with the highest of ``scores`` (M,) (the first of equals;
        a state without rows: its start)."""
        scores = np.asarray(scores, dtype=np.float64)
        starts, sizes = self.starts, self.sizes
        rows = starts.copy()
        filled = sizes > 0
        if not filled.any():
            return rows
        maxes = np.maximum.reduceat(scores, starts[filled])
        state = np.repeat(np.flatnonzero(filled), sizes[filled])
        at_max = np.flatnonzero(scores == np.repeat(maxes, sizes[filled]))
        first = at_max[np.r_[True, state[at_max][1:] != state[at_max][:-1]]]
        rows[state[first]] = first
        return rows

    def gain_ratio(self, scores: np.ndarray, mask: np.ndarray | None = None) -> float:
        """Mean over the states with something to gain (best > 0; also in ``mask`` (S,) bool) of the
        valid gain of the highest-scoring row over the best valid gain: 1 is the oracle's choice."""
        keep = (self.best > 0) & (self.sizes > 0) & (True if mask is None else mask)
        if not keep.any():
            return float("nan")
        chosen = self.gains[self.choices(scores)]
        return float(np.mean(chosen[keep] / self.best[keep]))

    def labelled(self, target: str) -> "RankingData":
        """The same rows with ``target``'s labels ("valid" gains or "all" gains)."""
        if target not in ("valid", "all"):
            raise ValueError(f"target={target!r}: 'valid' (gains of views that pass the overlap rule) or 'all'")
        if not len(self.target) or self.target[0] == target:
            return self
        return dataclasses.replace(self, gains=self.other, other=self.gains, best=self.best_other,
                                   best_other=self.best, mean=self.mean_other, mean_other=self.mean,
                                   farthest=self.farthest_other, farthest_other=self.farthest,
                                   target=np.full(len(self.target), target))

    def subset(self, states: np.ndarray) -> "RankingData":
        """The states ``states`` (sorted indices), with their rows."""
        states = np.asarray(states, dtype=np.int64)
        starts = self.starts
        rows = np.concatenate([np.arange(starts[s], starts[s] + self.sizes[s]) for s in states]) if len(states) else \
            np.zeros(0, dtype=np.int64)
        per_row = {"features", "gains", "other", "views"}
        return RankingData(**{name: getattr(self, name)[rows if name in per_row else states]
                              for name in RankingData.__dataclass_fields__})


def concatenate(parts: list[RankingData]) -> RankingData:
    """One ``RankingData`` of ``parts`` in order."""
    if not parts:
        raise ShardError("no states to rank: give shards that hold some")
    fields = RankingData.__dataclass_fields__
    return RankingData(**{name: np.concatenate([getattr(part, name) for part in parts]) for name in fields})


def bundle_for(views: ViewSet, config: SimConfig, rays: tuple[int, int] = BUNDLE) -> RayBundle:
    """The ``RayBundle`` of a view set in a scene (grid and sensor), made once per process."""
    grid = config.scene_grid
    key = (views.positions.tobytes(), grid.size, grid.extent, config.sensor.hfov, config.sensor.vfov,
           config.sensor.far, tuple(rays))
    if key not in _BUNDLES:
        if len(_BUNDLES) > 16:
            _BUNDLES.clear()
        _BUNDLES[key] = RayBundle.build(views, grid, config.sensor, *rays)
    return _BUNDLES[key]


def layout_label(config: SimConfig) -> str:
    """"hemisphere-500", "tammes-128", ...: a scene's candidate views in a word."""
    return f"{config.views.layout}-{config.views.count}" + ("-hemi" if config.views.reach == "hemi" else "")


def shard_rows(path: Path, rays: tuple[int, int] = BUNDLE, sample: int = 0, seed: int = 0,
               states: np.ndarray | None = None) -> RankingData:
    """The ranking rows of one shard's states (all, or ``states``: sorted sample indices); see the
    module docstring. ShardError naming the shard when it lacks what ranking needs."""
    with Shard(path) as shard:
        for name in ("gains", "overlaps", "last_view", "mesh_id"):
            if not shard.has(name):
                raise ShardError(f"{path}: no {name} (imported data?): rank on shards written by nbvdata generate")
        try:
            config = from_dict(SimConfig, shard.info.config or {})
        except ConfigError as error:
            raise ShardError(f"{path}: its recorded settings do not load ({error})") from None
        positions = shard["view_positions"]
        last = shard["last_view"]
        if len(last) and last.min() < 0:
            raise ShardError(f"{path}: states reached through poses that are no candidate view (a regression "
                             "--policy rollout): their scanned views are unknown; rank on other shards")
        run, step = shard["run"], shard["step"]
        try:
            taken = view_state(run, step, last, len(positions))
        except ValueError as error:
            raise ShardError(f"{path}: {error}") from None
        index = np.arange(len(shard)) if states is None else np.asarray(states, dtype=np.int64)
        chosen = slice(None) if states is None else index  # h5py reads a slice fastest
        grids = shard.grids(chosen)
        gains, overlaps = shard.read("gains", chosen), shard.read("overlaps", chosen)
        mesh_ids = shard.read("mesh_id", chosen).astype(str)
        coverage = shard.read("coverage", chosen)[:, 0]
    views = ViewSet(positions, look_at_rotations(positions))
    bundle = bundle_for(views, config, rays)
    valid = np.where(overlaps.astype(np.float64) >= config.oracle.min_overlap, gains, 0.0).astype(np.float32)
    gains = gains.astype(np.float32)
    units = views.unit_positions
    features, labels, others, rows_views, sizes, best, best_other, mean, mean_other, farthest, farthest_other = (
        [] for _ in range(11))
    for k, i in enumerate(index):
        scanned = positions[taken[i]]
        free = np.flatnonzero(~taken[i])
        rows = free
        if sample and len(free) > sample:
            rows = _sample_views(free, valid[k, free] + gains[k, free], sample, seed, mesh_ids[k], int(run[i]),
                                 int(step[i]))
        state_features = view_features(grids[k], scanned, bundle)
        features.append(state_features[rows])
        labels.append(valid[k, rows])
        others.append(gains[k, rows])
        rows_views.append(rows.astype(np.int32))
        sizes.append(len(rows))
        best.append(valid[k, free].max() if len(free) else 0.0)
        best_other.append(gains[k, free].max() if len(free) else 0.0)
        mean.append(valid[k, free].mean() if len(free) else 0.0)
        mean_other.append(gains[k, free].mean() if len(free) else 0.0)
        choice = farthest_view(units, scanned)
        farthest.append(valid[k, choice])
        farthest_other.append(gains[k, choice])
    width = len(FEATURES)

    def joined(parts: list, dtype, shape=(0,)) -> np.ndarray:
        return np.concatenate(parts).astype(dtype) if parts else np.zeros(shape, dtype=dtype)

    return RankingData(
        features=joined(features, np.float32, (0, width)), gains=joined(labels, np.float32),
        other=joined(others, np.float32), views=joined(rows_views, np.int32),
        sizes=np.array(sizes, dtype=np.int64), best=np.array(best, dtype=np.float32),
        best_other=np.array(best_other, dtype=np.float32), mean=np.array(mean, dtype=np.float32),
        mean_other=np.array(mean_other, dtype=np.float32), farthest=np.array(farthest, dtype=np.float32),
        farthest_other=np.array(farthest_other, dtype=np.float32), target=np.full(len(index), "valid"),
        steps=step[index].astype(np.int32), mesh_ids=mesh_ids,
        layouts=np.full(len(index), layout_label(config)), coverage=np.asarray(coverage, dtype=np.float32))


def _sample_views(free: np.ndarray, gains: np.ndarray, sample: int, seed: int, mesh_id: str, run: int,
                  step: int) -> np.ndarray:
    """``sample`` of the views ``free`` (sorted): the ``sample // 4`` of largest gain (``gains``, the
    lowest index among equals) and a seeded random choice of the others, sorted."""
    top = sample // 4
    order = np.lexsort((free, -gains.astype(np.float64)))
    keep, rest = order[:top], order[top:]
    rng = np.random.default_rng([seed, zlib.crc32(mesh_id.encode()), run, step])
    chosen = rng.choice(rest, size=sample - top, replace=False)
    return np.sort(free[np.concatenate([keep, chosen])])


def cache_path(cache: Path, digest: str, rays: tuple[int, int], sample: int, seed: int,
               states: np.ndarray | None) -> Path:
    """Where ``cached_rows`` keeps a shard's rows: named by its sha256 and every argument."""
    chosen = "all" if states is None else hashlib.sha256(np.asarray(states, dtype=np.int64).tobytes()).hexdigest()[:12]
    return Path(cache) / f"{digest[:24]}-{rays[0]}x{rays[1]}-s{sample}-seed{seed}-{chosen}-f{len(FEATURES)}-v3.npz"


def cached_rows(path: Path, cache: Path | None, rays: tuple[int, int], sample: int, seed: int,
                states: np.ndarray | None = None, digest: str | None = None) -> RankingData:
    """``shard_rows``, kept in ``cache`` (a folder; None: no cache) under the shard's sha256
    (``digest``, e.g. from its manifest; else computed) and the arguments, so that a second fit
    on the same shards reads them instead of walking every grid again."""
    if cache is None:
        return shard_rows(path, rays, sample, seed, states)
    target = cache_path(cache, digest or sha256_file(path), rays, sample, seed, states)
    if target.is_file():
        try:
            with np.load(target, allow_pickle=False) as stored:
                return RankingData(**{key: stored[key] for key in RankingData.__dataclass_fields__})
        except (OSError, KeyError, ValueError):
            target.unlink(missing_ok=True)  # a damaged cache entry is made again
    rows = shard_rows(path, rays, sample, seed, states)
    target.parent.mkdir(parents=True, exist_ok=True)
    partial = target.with_name(target.name + ".partial.npz")
    np.savez(partial, **{key: getattr(rows, key) for key in RankingData.__dataclass_fields__})
    partial.replace(target)
    return rows
