"""Ranking data from shards: every state's candidate views as rows of per-view features
(``nbvdata.simulation.viewfeatures``), each with the exact gain the shard holds for it.

A state is one query; its rows are the candidate views it has not scanned (a scanned view is
marked by the run's ``last_view`` history, ``nbvdata.schema.shards.view_state``). ``sample`` > 0 keeps
at most that many rows per state - its ``sample // 4`` views of largest valid gain plus gain, and a seeded
random choice of the rest (the seed derives from ``seed``, the mesh id, the run and the step,
so the rows do not depend on the number of workers) - for training; 0 keeps every row, for
validation (the gain ratio of a choice needs every view).

Two labels per row: its gain (the observable coverage it would add) and its *valid* gain, the
gain when the view's overlap passes the shard's ``oracle.min_overlap``, else 0 (the ground
truth's rule: the next-best-view is the valid view with the largest gain). ``RankingData.gains``
holds one of them (``target``: "valid" or "all"), ``RankingData.labelled`` gives the other.

Also what every model of per-view rows shares (rankers, cover models, the surface prior, SCVP's
network): ``sources_parts`` (manifests and folders split by one mesh split into ``Part`` s),
``check_rows`` and ``check_grid`` (their settings and the grid they were trained on),
``grid_scene`` and ``finite`` (what their files and metrics record).
"""

from __future__ import annotations

import dataclasses
import hashlib
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nbvdata.core.config import ConfigError, SimConfig, from_dict
from nbvdata.core.files import sha256_file, shown_path
from nbvdata.core.views import ViewSet, farthest_view, look_at_rotations
from nbvdata.schema.manifest import mesh_split, open_verified
from nbvdata.schema.shards import Shard, ShardError, shard_files, view_state
from nbvdata.simulation.viewfeatures import BUNDLE, FEATURES, RayBundle, shadow_weights, view_features

_BUNDLES: dict[tuple, RayBundle] = {}


@dataclass
class RankingData:
    """Rows grouped by state, states in order.

    features : (M, F) float32, the columns ``nbvdata.simulation.viewfeatures.FEATURES``
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
               states: np.ndarray | None = None, prior=None) -> RankingData:
    """The ranking rows of one shard's states (all, or ``states``: sorted sample indices); see the
    module docstring; ``prior``: a surface prior (``nbvtrain.ranking.surfaceprior``) for the
    ``expected_surface`` columns (None: 0). ShardError naming the shard when it lacks what ranking
    needs."""
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
        shadow = shadow_weights(grids[k], scanned, bundle)
        surface = prior.probabilities(grids[k], shadow) if prior is not None else None
        state_features = view_features(grids[k], scanned, bundle, surface=surface, shadow=shadow)
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
               states: np.ndarray | None, prior=None) -> Path:
    """Where ``cached_rows`` keeps a shard's rows: named by its sha256 and every argument (a surface
    prior by the sha256 of its model text)."""
    chosen = "all" if states is None else hashlib.sha256(np.asarray(states, dtype=np.int64).tobytes()).hexdigest()[:12]
    surface = "" if prior is None else f"-p{prior_digest(prior)[:12]}"
    return Path(cache) / f"{digest[:24]}-{rays[0]}x{rays[1]}-s{sample}-seed{seed}-{chosen}{surface}-f{len(FEATURES)}-v3.npz"


def prior_digest(prior) -> str:
    """The sha256 of a surface prior's model text: what its probabilities are a function of."""
    from nbvtrain.ranking._lightgbm import TEXT_KEY

    return prior.to_dict()[TEXT_KEY]


def cached_rows(path: Path, cache: Path | None, rays: tuple[int, int], sample: int, seed: int,
                states: np.ndarray | None = None, digest: str | None = None, prior=None) -> RankingData:
    """``shard_rows``, kept in ``cache`` (a folder; None: no cache) under the shard's sha256
    (``digest``, e.g. from its manifest; else computed) and the arguments, so that a second fit
    on the same shards reads them instead of walking every grid again."""
    if cache is None:
        return shard_rows(path, rays, sample, seed, states, prior)
    target = cache_path(cache, digest or sha256_file(path), rays, sample, seed, states, prior)
    if target.is_file():
        try:
            with np.load(target, allow_pickle=False) as stored:
                return RankingData(**{key: stored[key] for key in RankingData.__dataclass_fields__})
        except (OSError, KeyError, ValueError):
            target.unlink(missing_ok=True)  # a damaged cache entry is made again
    rows = shard_rows(path, rays, sample, seed, states, prior)
    target.parent.mkdir(parents=True, exist_ok=True)
    partial = target.with_name(target.name + ".partial.npz")
    np.savez(partial, **{key: getattr(rows, key) for key in RankingData.__dataclass_fields__})
    partial.replace(target)
    return rows


def check_rows(rays: tuple[int, int], sample: int) -> None:
    """ConfigError unless ``rays`` is (width, height) >= 1 and ``sample`` 0 or >= 4 rows per state:
    the settings of the per-view rows a model of features trains on (a ranker, ``nbvtrain.ranking.covermodel``)."""
    if len(rays) != 2 or min(rays) < 1:
        raise ConfigError(f"rays={rays}: give WIDTHxHEIGHT rays per view, each >= 1")
    if sample < 0 or 0 < sample < 4:
        raise ConfigError(f"sample={sample}: give 0 (every row) or at least 4 rows per state")


def check_grid(scene: dict, config: SimConfig, where: str, what: str) -> None:
    """ConfigError when ``config``'s grid is not ``scene``'s ({grid_size, grid_extent}), the one ``what``
    (a ranker, a cover model) was trained on."""
    grid = config.scene_grid
    size, extent = scene.get("grid_size"), scene.get("grid_extent")
    if size is not None and (size != grid.size or abs(extent - grid.extent) > 1e-6):
        raise ConfigError(f"{where}: {what} trained on {size}^3 grids of {extent:.4f} m, this run's are "
                          f"{grid.size}^3 of {grid.extent:.4f} m: run with the grid settings it was trained with")


@dataclass(frozen=True)
class Part:
    """The states of one shard a part uses: ``states`` (sorted sample indices); ``digest`` its sha256 when known."""

    path: Path
    states: np.ndarray
    digest: str | None = None


def sources_parts(items: list[Path], root: Path | None = None, val_fraction: float = 0.2,
                  seed: int = 0) -> tuple[list[Part], list[Part], list[dict]]:
    """(train parts, val parts, a record per source) of manifests and shard folders (a manifest's
    record: its name, version and sha256; a folder's: its path as ``shown_path`` gives it - no
    local roots, for the model files that carry the records).

    One split holds for every source, so that no object trains under one view set and validates
    under another: the mesh split of the first manifest (its val meshes validate, its test meshes
    are left out, every other mesh trains), or without a manifest ``nbvdata.schema.manifest.mesh_split``
    of all the folders' meshes."""
    if not items:
        raise ConfigError("no data given: nbvtrain fit MANIFEST.json [MANIFEST.json ...] --model viewrank-gbm")
    manifests = [Path(item) for item in items if Path(item).suffix == ".json"]
    if root is not None and len(manifests) != 1:
        raise ConfigError("--root: give it with one manifest (each of several finds its shards at the root it records)")
    shards: list[tuple[Path, str | None]] = []
    records = []
    held: dict[str, set] = {}
    for item in manifests:
        published = open_verified(item, root)
        if not held:
            mesh = published.content["splits"].get("mesh", {})
            if not isinstance(mesh, dict) or "unavailable" in mesh:
                raise ConfigError(f"{item}: no mesh split ({mesh.get('unavailable', 'none recorded')}): a ranker "
                                  "validates on whole meshes")
            held = {part: set(mesh.get(part, {}).get("meshes", [])) for part in ("val", "test")}
            records.append({"split_from": published.label})
        shards += [(path, entry["sha256"]) for entry, path in zip(published.content["shards"], published.shard_paths)]
        records.append({key: published.identity[key] for key in ("name", "version", "sha256")})
    folders = [item for item in items if Path(item).suffix != ".json"]
    shards += [(path, None) for path in (shard_files(folders) if folders else [])]
    ids = []
    for path, _ in shards:
        with Shard(path) as shard:
            if not shard.has("mesh_id"):
                raise ShardError(f"{path}: no mesh ids (imported data): a ranker validates on whole meshes")
            ids.append(shard["mesh_id"].astype(str))
    if not held:
        parts = mesh_split(np.concatenate(ids) if ids else np.zeros(0, dtype=str), val_fraction, 0.0, seed)
        if isinstance(parts, str):
            raise ShardError(f"the shards of {', '.join(map(str, folders))}: {parts}; give more meshes")
        held = {"val": set(parts["val"].tolist()), "test": set()}
        records.append({"folders": [shown_path(folder) for folder in folders], "val_fraction": val_fraction,
                        "seed": seed})
    elif folders:
        records.append({"folders": [shown_path(folder) for folder in folders]})
    train, val = [], []
    for (path, digest), mesh_ids in zip(shards, ids):
        is_val = np.isin(mesh_ids, list(held["val"]))
        is_train = ~is_val & ~np.isin(mesh_ids, list(held["test"]))
        if is_train.any():
            train.append(Part(path, np.flatnonzero(is_train), digest))
        if is_val.any():
            val.append(Part(path, np.flatnonzero(is_val), digest))
    records.append({"val_meshes": len(held["val"]), "test_meshes_left_out": len(held["test"])})
    if not train or not val:
        raise ConfigError("a ranker needs training and validation meshes: the split left "
                          f"{'no training' if not train else 'no validation'} states")
    return train, val, records


def grid_scene(path: Path) -> dict:
    """The grid of a shard's scene: {grid_size, grid_extent} (metres)."""
    from nbvdata.core.config import SimConfig, from_dict

    with Shard(path) as shard:
        grid = from_dict(SimConfig, shard.info.config or {}).scene_grid
    return {"grid_size": grid.size, "grid_extent": round(float(grid.extent), 9)}


def finite(value):
    """``value`` with every NaN or infinite float as None (JSON has no NaN): a gain ratio of no state."""
    if isinstance(value, dict):
        return {key: finite(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite(item) for item in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value
