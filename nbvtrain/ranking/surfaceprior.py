"""A surface prior: P(surface | the partial grid around an unknown voxel), learned from the meshes'
own surface voxels (the shards' ``surface``, ``state.surface``), so that a planner can count what
each view would newly see of the surface still hidden - SCONE's and Monica & Aleotti's idea (an
occupancy field first, then what each view sees of it), on a CPU.

Model: LightGBM (binary log loss) over the neighbourhood of each unknown voxel (``VOXEL_FEATURES``):
its counts of occupied, free and unknown voxels in 3^3, 5^3 and 7^3 cubes, its chessboard distances
to the nearest occupied and free voxels, on how many axes it lies between two occupied voxels within
``SANDWICH`` voxels (inside a seen shell), its ``proximity_shadow`` weight (how near it lies behind a
hit along an earlier scan's ray), its height and distance from the grid's centre, and the grid's
unknown share. Why trees, not a 3D network: a CPU trains them on millions of voxels in minutes,
they take these hand-made cues as they are, and a decision needs them only near the surface seen:
unknown voxels within ``REACH`` voxels of an occupied one are predicted, every other unknown voxel
takes the training data's rate for such voxels (``far_rate``), known voxels 0 (free) or 1
(occupied: already seen, no new surface there).

``nbvtrain fit SHARDS_OR_MANIFESTS --model surface-gbm`` trains one (the ranker's mesh split,
``nbvtrain.ranking.rankdata.sources_parts``; shards made with ``--set state.surface=true``) into
``surface.json`` (plain data: the feature names, the scene's grid, ``far_rate``, how it was trained,
LightGBM's text with its sha256) and ``metrics.json``: precision and recall of the surface voxels
among the unknown ones at P >= 0.5, by scan step, on the validation meshes.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from nbvdata.core.config import SimConfig, from_dict
from nbvdata.core.files import write_atomic
from nbvdata.core.views import ViewSet, look_at_rotations
from nbvdata.schema.shards import Shard, ShardError, has_surface, view_state
from nbvdata.simulation.viewfeatures import shadow_weights
from nbvtrain.networks.checkpoint import CheckpointError
from nbvtrain.ranking.rankdata import bundle_for, check_grid, finite, grid_scene, sources_parts

FORMAT = "nbvtrain-surface"
FORMAT_VERSION = 1
USE_FIT = "pass a model written by nbvtrain fit --model surface-gbm (runs/NAME/surface.json)"
REACH = 4
"""Unknown voxels within this many voxels (chessboard) of an occupied one are predicted."""
SANDWICH = 6
"""``between``: occupied voxels within this many voxels on both sides along an axis."""
CAP = 8  # distances are capped here
VOXEL_FEATURES = ("occupied_3", "free_3", "unknown_3", "occupied_5", "free_5", "unknown_5", "occupied_7", "free_7",
                  "unknown_7", "to_occupied", "to_free", "between", "shadow", "height", "radius", "grid_unknown")
"""The columns of ``voxel_features``, in order (module docstring)."""


def voxel_features(probabilities: np.ndarray, shadow: np.ndarray) -> np.ndarray:
    """(n^3, len(VOXEL_FEATURES)) float32 of every voxel of the (n, n, n) grid (0.5 = unknown) with
    its (n^3,) ``proximity_shadow`` weights (``nbvdata.simulation.viewfeatures.shadow_weights``)."""
    grid = np.asarray(probabilities, dtype=np.float32)
    n = grid.shape[0]
    occupied, unknown = grid > 0.5, grid == 0.5
    free = ~occupied & ~unknown
    columns = []
    for size in (3, 5, 7):
        for mask in (occupied, free, unknown):
            columns.append(ndimage.uniform_filter(mask.astype(np.float32), size=size, mode="constant") * size ** 3)
    for mask in (occupied, free):
        distance = ndimage.distance_transform_cdt(~mask, metric="chessboard") if mask.any() else np.full(grid.shape, CAP)
        columns.append(np.minimum(distance, CAP).astype(np.float32))
    between = np.zeros(grid.shape, dtype=np.float32)
    for axis in range(3):
        before = np.zeros(grid.shape, dtype=bool)
        after = np.zeros(grid.shape, dtype=bool)
        for step in range(1, SANDWICH + 1):
            before |= _shifted(occupied, axis, step)
            after |= _shifted(occupied, axis, -step)
        between += before & after
    columns.append(between)
    columns.append(np.asarray(shadow, dtype=np.float32).reshape(grid.shape))
    index = np.indices(grid.shape, dtype=np.float32)
    centre = (n - 1) / 2
    columns.append(index[2] / n)
    columns.append(np.sqrt(((index - centre) ** 2).sum(axis=0)) / n)
    columns.append(np.full(grid.shape, unknown.mean(), dtype=np.float32))
    return np.stack([column.reshape(-1) for column in columns], axis=1).astype(np.float32)


def _shifted(mask: np.ndarray, axis: int, step: int) -> np.ndarray:
    """``mask`` moved ``step`` voxels along ``axis`` (positive: each voxel sees the one ``step`` before it), empty beyond the edge."""
    out = np.zeros_like(mask)
    source = [slice(None)] * 3
    target = [slice(None)] * 3
    if step > 0:
        source[axis], target[axis] = slice(0, -step), slice(step, None)
    else:
        source[axis], target[axis] = slice(-step, None), slice(0, step)
    out[tuple(target)] = mask[tuple(source)]
    return out


def candidates(probabilities: np.ndarray) -> np.ndarray:
    """(n^3,) bool: the unknown voxels within ``REACH`` of an occupied one (the ones predicted)."""
    grid = np.asarray(probabilities)
    occupied = grid > 0.5
    if not occupied.any():
        return np.zeros(grid.size, dtype=bool)
    near = ndimage.distance_transform_cdt(~occupied, metric="chessboard") <= REACH
    return ((grid == 0.5) & near).reshape(-1)


class SurfacePrior:
    """A trained ``surface-gbm``: ``probabilities(grid, shadow) -> (n, n, n)`` P(surface) per voxel."""

    kind = "surface-gbm"

    def __init__(self, booster, scene: dict, far_rate: float, training: dict):
        from nbvtrain.ranking.trees import compile_trees

        self.booster, self.scene, self.far_rate, self.training = booster, scene, float(far_rate), training
        self.trees = compile_trees(booster.model_to_string())
        self.path: Path | None = None

    def probabilities(self, probabilities: np.ndarray, shadow: np.ndarray) -> np.ndarray:
        """(n, n, n) float64: P(surface) of each unknown voxel (the model near the surface seen, the
        far rate elsewhere), 0 for free and occupied voxels (no new surface to see there)."""
        grid = np.asarray(probabilities)
        out = np.where(grid == 0.5, self.far_rate, 0.0).reshape(-1)
        near = candidates(grid)
        if near.any():
            raw = self.trees.raw(voxel_features(grid, shadow)[near])
            out[near] = 1.0 / (1.0 + np.exp(-raw))
        return out.reshape(grid.shape)

    def check_scene(self, config: SimConfig, where: str) -> None:
        check_grid(self.scene, config, where, "a surface prior")

    def to_dict(self) -> dict:
        """The model file's content (plain data; ``load_surface_prior`` reads it)."""
        from nbvtrain.ranking._lightgbm import TEXT_KEY, text_digest

        model = self.booster.model_to_string()
        return {"format": FORMAT, "format_version": FORMAT_VERSION, "kind": self.kind,
                "features": list(VOXEL_FEATURES), "reach": REACH, "scene": self.scene, "far_rate": self.far_rate,
                "training": self.training, TEXT_KEY: text_digest(model), "lightgbm": model}

    def save(self, path: Path) -> None:
        write_atomic(Path(path), json.dumps(self.to_dict(), indent=1, allow_nan=False))


def surface_prior_from(head, where: Path) -> SurfacePrior:
    """The prior of a model file's content ``head`` (a surface.json, or the prior a ranker carries);
    CheckpointError naming ``where`` and the fix for anything else."""
    from nbvtrain.ranking._lightgbm import load_booster

    if not isinstance(head, dict) or head.get("format") != FORMAT or head.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(f"{where}: not a surface prior of format {FORMAT!r} {FORMAT_VERSION}; {USE_FIT}")
    missing = [key for key in ("features", "reach", "scene", "far_rate", "training") if key not in head]
    if missing:
        raise CheckpointError(f"{where}: not a surface prior (no {', '.join(missing)}); {USE_FIT}")
    if head["features"] != list(VOXEL_FEATURES) or head["reach"] != REACH:
        raise CheckpointError(f"{where}: a surface prior of other voxel features; retrain it with nbvtrain fit --model "
                              "surface-gbm")
    booster = load_booster(head, where, USE_FIT, CheckpointError)
    if booster.num_feature() != len(VOXEL_FEATURES):
        raise CheckpointError(f"{where}: its LightGBM model reads {booster.num_feature()} features, not "
                              f"{len(VOXEL_FEATURES)}; {USE_FIT}")
    prior = SurfacePrior(booster, head["scene"], float(head["far_rate"]), head["training"])
    prior.path = Path(where)
    return prior


def load_surface_prior(path: str | Path) -> SurfacePrior:
    """The surface prior in ``path`` (``surface.json``); CheckpointError in one line for anything else."""
    from nbvtrain.ranking._lightgbm import read_model_json

    return surface_prior_from(read_model_json(Path(path), "a surface prior", USE_FIT, CheckpointError), Path(path))


# ---------------------------------------------------------------------------------------------
# Training


@dataclass(frozen=True)
class SurfacePriorConfig:
    """How ``surface-gbm`` is trained (``nbvtrain fit --model surface-gbm``)."""

    every: int = 4
    """Training states: every ``every``-th state of each shard (validation: the same)."""
    voxels: int = 1500
    """Training voxels per state at most (a seeded sample of its predicted ones; validation keeps all)."""
    seed: int = 0
    trees: int = 300
    learning_rate: float = 0.1
    leaves: int = 31
    min_rows: int = 200
    patience: int = 20
    threads: int = 2


@dataclass
class VoxelRows:
    """Rows of predicted voxels: ``features`` (M, K) float32, ``surface`` (M,) bool labels, ``steps``
    (M,) the state's scans; per state (S,): ``hidden`` its unknown surface voxels, ``far`` its far
    unknown voxels and ``far_surface`` the surface among them."""

    features: np.ndarray
    surface: np.ndarray
    steps: np.ndarray
    hidden: np.ndarray
    far: np.ndarray
    far_surface: np.ndarray
    state_steps: np.ndarray


def shard_voxel_rows(path: Path, states: np.ndarray, config: SurfacePriorConfig, sample: bool) -> VoxelRows:
    """The voxel rows of every ``config.every``-th of ``states`` of one shard (``sample``: at most
    ``config.voxels`` per state, seeded by the shard's name and the state)."""
    import zlib

    with Shard(path) as shard:
        settings = shard.info.config or {}
        if not has_surface(settings):
            raise ShardError(f"{path}: no surface voxels; generate with --set state.surface=true")
        chosen = np.asarray(states, dtype=np.int64)[::config.every]
        positions = shard["view_positions"]
        taken = view_state(shard["run"], shard["step"], shard["last_view"], len(positions))
        grids = shard.grids(chosen) if len(chosen) else np.zeros((0,) + (1,) * 3)
        truth = shard["surface"].reshape(-1)
        steps = shard["step"]
    sim = from_dict(SimConfig, settings)
    bundle = bundle_for(ViewSet(positions, look_at_rotations(positions)), sim, (1, 1))
    parts: dict[str, list] = {name: [] for name in VoxelRows.__dataclass_fields__}
    for k, i in enumerate(chosen):
        grid = grids[k]
        shadow = shadow_weights(grid, positions[taken[i]], bundle)
        near = candidates(grid)
        rows = np.flatnonzero(near)
        if sample and len(rows) > config.voxels:
            rng = np.random.default_rng([config.seed, zlib.crc32(path.name.encode()), int(i)])
            rows = np.sort(rng.choice(rows, size=config.voxels, replace=False))
        unknown = (grid == 0.5).reshape(-1)
        parts["features"].append(voxel_features(grid, shadow)[rows])
        parts["surface"].append(truth[rows])
        parts["steps"].append(np.full(len(rows), steps[i], dtype=np.int32))
        parts["hidden"].append(int((unknown & truth).sum()))
        parts["far"].append(int((unknown & ~near).sum()))
        parts["far_surface"].append(int((unknown & ~near & truth).sum()))
        parts["state_steps"].append(int(steps[i]))
    width = len(VOXEL_FEATURES)
    return VoxelRows(
        features=np.concatenate(parts["features"]) if parts["features"] else np.zeros((0, width), np.float32),
        surface=np.concatenate(parts["surface"]).astype(bool) if parts["surface"] else np.zeros(0, bool),
        steps=np.concatenate(parts["steps"]) if parts["steps"] else np.zeros(0, np.int32),
        **{name: np.array(parts[name], dtype=np.int64) for name in ("hidden", "far", "far_surface", "state_steps")})


def _rows_one_thread(part, config: SurfacePriorConfig, sample: bool) -> VoxelRows:
    import numba

    numba.set_num_threads(1)
    return shard_voxel_rows(part.path, part.states, config, sample)


def voxel_rows(parts: list, config: SurfacePriorConfig, sample: bool, workers: int) -> VoxelRows:
    from joblib import Parallel, delayed

    jobs = (delayed(_rows_one_thread)(part, config, sample) for part in parts)
    found = (Parallel(n_jobs=workers, backend="loky")(jobs) if workers > 1
             else [shard_voxel_rows(part.path, part.states, config, sample) for part in parts])
    if not found:
        raise ShardError("no states with surface voxels")
    return VoxelRows(**{name: np.concatenate([getattr(rows, name) for rows in found])
                        for name in VoxelRows.__dataclass_fields__})


def completion(probabilities: np.ndarray, rows: VoxelRows) -> dict:
    """Precision and recall of the hidden surface voxels at P >= 0.5 over the unknown voxels (far
    ones predicted at the far rate), overall and by scan step; the share of the hidden surface near
    what was seen (within ``REACH``)."""
    predicted = probabilities >= 0.5

    def figures(rows_mask: np.ndarray, state_mask: np.ndarray) -> dict:
        hits = int((predicted & rows.surface & rows_mask).sum())
        claimed = int((predicted & rows_mask).sum())
        hidden = int(rows.hidden[state_mask].sum())
        near = int((rows.surface & rows_mask).sum())
        return {"states": int(state_mask.sum()), "precision": hits / claimed if claimed else float("nan"),
                "recall": hits / hidden if hidden else float("nan"), "near_share": near / hidden if hidden else float("nan")}

    out = {"all": figures(np.ones(len(rows.surface), bool), np.ones(len(rows.hidden), bool))}
    out["by_step"] = {int(step): figures(rows.steps == step, rows.state_steps == step)
                      for step in np.unique(rows.state_steps) if step <= 12}
    return out


def fit_surface_prior(items: list[Path], config: SurfacePriorConfig, out: Path, root: Path | None = None,
                      workers: int = 2) -> dict:
    """Train ``surface-gbm`` on the states of ``items`` (manifests or shard folders with surface
    voxels; the split of ``nbvtrain.ranking.rankdata.sources_parts``) into ``out``: ``surface.json`` and
    ``metrics.json``; returns the metrics."""
    from nbvtrain.ranking._lightgbm import lightgbm

    started = time.perf_counter()
    train_parts, val_parts, records = sources_parts(items, root, seed=config.seed)
    train = voxel_rows(train_parts, config, True, workers)
    val = voxel_rows(val_parts, config, False, workers)
    featured = time.perf_counter()
    far_rate = float(train.far_surface.sum() / max(train.far.sum(), 1))
    params = {"objective": "binary", "metric": "binary_logloss", "learning_rate": config.learning_rate,
              "num_leaves": config.leaves, "min_data_in_leaf": config.min_rows, "feature_fraction": 0.9,
              "num_threads": config.threads, "deterministic": True, "force_row_wise": True, "seed": config.seed,
              "verbosity": -1}
    train_set = lightgbm.Dataset(train.features, label=train.surface.astype(np.int32),
                                 feature_name=list(VOXEL_FEATURES), free_raw_data=False)
    val_set = lightgbm.Dataset(val.features, label=val.surface.astype(np.int32), reference=train_set)
    booster = lightgbm.train(params, train_set, num_boost_round=config.trees, valid_sets=[val_set],
                             valid_names=["val"], callbacks=[lightgbm.early_stopping(config.patience, verbose=False)])
    best = booster.best_iteration or booster.current_iteration()
    booster = lightgbm.Booster(model_str=booster.model_to_string(num_iteration=best))
    prior = SurfacePrior(booster, grid_scene(train_parts[0].path), far_rate,
                         asdict(config) | {"rounds": best, "sources": records})
    out.mkdir(parents=True, exist_ok=True)
    prior.save(out / "surface.json")
    probabilities = 1.0 / (1.0 + np.exp(-prior.trees.raw(val.features)))
    metrics = {"model": "surface-gbm", "file": "surface.json", "rounds": best, "far_rate": far_rate,
               "val": completion(probabilities, val), "base_rate": float(val.surface.mean()) if len(val.surface) else None,
               "train_voxels": int(len(train.surface)), "val_voxels": int(len(val.surface)),
               "train_states": int(len(train.hidden)), "val_states": int(len(val.hidden)),
               "feature_seconds": round(featured - started, 1),
               "model_seconds": round(time.perf_counter() - featured, 1), "sources": records}
    (out / "metrics.json").write_text(json.dumps(finite(metrics), indent=1, allow_nan=False) + "\n")
    return metrics
