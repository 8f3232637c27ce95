"""A set-cover model for any view set: each candidate view's membership in the state's exact
cover (``nbvdata.simulation.setcover``), predicted from the ranker's per-view features
(``nbvdata.simulation.viewfeatures``) by one LightGBM classifier (``cover-gbm``), so that one model plans
covers on SCVP's 32 views, PC-NBV's 33, the Tammes-128 sphere or the paper's 500.

Rows: a state's unscanned views with their features (``nbvtrain.ranking.rankdata``, the ranker's rows and
feature cache), each labelled 1 when the state's cover holds it. Training keeps every row by
default (``sample`` 0: a sample of rows would skew the probabilities of the larger view sets),
so that the probabilities are calibrated on every view set and their sum over a state's views is
the expected size of its cover. The predicted set of a state is its ``expected_sets``: its k most
probable views, k that sum rounded. A single threshold cannot hold across view sets (measured:
the best one for all of them, 0.25, planned 26 views of SCVP's 32 where the cover takes 16, and 6
of Tammes-128's where it takes 20); ``choose_threshold`` still records the best threshold for
comparison.

The model file ``cover.json`` is plain data (``FORMAT``: the feature names, the ray bundle, the
scene's grid, the threshold, how it was trained and LightGBM's text model), read without
unpickling anything (``load_cover_model``).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from nbvdata.core.config import SimConfig
from nbvdata.core.files import write_atomic
from nbvdata.core.views import ViewSet
from nbvdata.schema.shards import Shard, ShardError, has_covers
from nbvdata.simulation.viewfeatures import BASE, BUNDLE, FEATURES, view_features
from nbvtrain.networks.checkpoint import CheckpointError
from nbvtrain.ranking.rankdata import RankingData, bundle_for, check_grid, check_rows

FORMAT = "nbvtrain-cover"
FORMAT_VERSION = 1
USE_FIT = "pass a model written by nbvtrain fit --model cover-gbm (runs/NAME/cover.json)"
THRESHOLDS = np.round(np.arange(0.05, 0.951, 0.025), 3)  # the thresholds choose_threshold tries


@dataclass(frozen=True)
class CoverModelConfig:
    """How ``cover-gbm`` is trained (``nbvtrain fit --model cover-gbm``)."""

    rays: tuple[int, int] = BUNDLE
    """Rays per view of the features' coarse bundle (the ranker's: their cache is shared)."""
    sample: int = 0
    """Training rows per state at most (0: all, the default; validation keeps all)."""
    seed: int = 0
    trees: int = 600
    """Boosting rounds at most (early stopping on the validation log loss may end sooner)."""
    learning_rate: float = 0.05
    leaves: int = 31
    min_rows: int = 100
    patience: int = 40
    threads: int = 2

    def __post_init__(self) -> None:
        check_rows(self.rays, self.sample)


@dataclass
class CoverRows:
    """Ranking rows with cover labels: ``member`` (M,) bool each row's view in its state's cover;
    ``optimal`` (S,) int the cover's size; ``proved`` (S,) bool whether it is proved optimal."""

    rows: RankingData
    member: np.ndarray
    optimal: np.ndarray
    proved: np.ndarray


def part_cover_rows(part, rays: tuple[int, int], sample: int, seed: int, cache: Path | None) -> CoverRows:
    """The rows of one ``nbvtrain.ranking.rankfit.Part`` (a shard's states) with their cover labels; ShardError
    for a shard without covers."""
    from nbvtrain.ranking.rankdata import cached_rows

    with Shard(part.path) as shard:
        if not has_covers(shard.info.config or {}):
            raise ShardError(f"{part.path}: no set-cover labels; generate with --set oracle.cover=true")
        covers = shard.read("cover", part.states).astype(bool)
        sizes = shard.read("cover_size", part.states).astype(np.int32)
        bounds = shard.read("cover_bound", part.states).astype(np.int32)
    rows = cached_rows(part.path, cache, rays, sample, seed, part.states, part.digest)
    state = np.repeat(np.arange(len(rows)), rows.sizes)
    return CoverRows(rows, covers[state, rows.views], sizes, bounds == sizes)


def _rows_one_thread(part, rays, sample, seed, cache) -> CoverRows:
    import numba

    numba.set_num_threads(1)
    return part_cover_rows(part, rays, sample, seed, cache)


def cover_rows(parts: list, config: CoverModelConfig, sample: int, cache: Path | None, workers: int,
               progress: bool, what: str) -> CoverRows:
    """The cover rows of ``parts`` in order, shard by shard in ``workers`` processes."""
    from joblib import Parallel, delayed
    from tqdm import tqdm

    from nbvtrain.ranking.rankdata import concatenate

    bar = tqdm(total=len(parts), desc=f"features ({what})", unit="shard", disable=not progress, dynamic_ncols=True)
    out = []
    jobs = (delayed(_rows_one_thread)(part, config.rays, sample, config.seed, cache) for part in parts)
    for result in (Parallel(n_jobs=workers, backend="loky", return_as="generator")(jobs) if workers > 1
                   else (part_cover_rows(part, config.rays, sample, config.seed, cache) for part in parts)):
        out.append(result)
        bar.update()
    bar.close()
    if not out:
        raise ShardError(f"no {what} states")
    return CoverRows(concatenate([part.rows for part in out]), np.concatenate([part.member for part in out]),
                     np.concatenate([part.optimal for part in out]), np.concatenate([part.proved for part in out]))


def predicted_sets(probabilities: np.ndarray, sizes: np.ndarray, threshold: float) -> np.ndarray:
    """(M,) bool the rows (grouped by state, ``sizes`` (S,)) whose probability reaches ``threshold``;
    a state none of whose rows does keeps its most probable one (a plan is never empty)."""
    chosen = np.asarray(probabilities) >= threshold
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    for start, size in zip(starts, sizes):
        if size and not chosen[start:start + size].any():
            chosen[start + int(np.argmax(probabilities[start:start + size]))] = True
    return chosen


def expected_sets(probabilities: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """(M,) bool per state (rows grouped by ``sizes`` (S,)) its k most probable rows, k the expected
    cover size round(sum of its probabilities), at least 1 (ties to the first row): a set rule that
    needs no threshold, so that it holds on view sets whose covers take half the views (SCVP's 32)
    and on those whose covers take a sixth (Tammes-128) alike."""
    probabilities = np.asarray(probabilities, dtype=np.float64)
    chosen = np.zeros(len(probabilities), dtype=bool)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    for start, size in zip(starts, sizes):
        if size:
            block = probabilities[start:start + size]
            count = min(max(int(np.rint(block.sum())), 1), int(size))
            chosen[start + np.argsort(-block, kind="stable")[:count]] = True
    return chosen


def set_quality(chosen: np.ndarray, member: np.ndarray, sizes: np.ndarray, optimal: np.ndarray,
                mask: np.ndarray | None = None) -> dict:
    """Mean predicted and optimal set size, their ratio, per-state precision, recall and F1 of
    membership, and the share of states whose predicted set is their cover exactly, over the
    states with a cover to predict (optimal > 0; also in ``mask`` (S,) bool)."""
    state = np.repeat(np.arange(len(sizes)), sizes)
    predicted = np.bincount(state, weights=chosen, minlength=len(sizes))
    hits = np.bincount(state, weights=chosen & member, minlength=len(sizes))
    wrong = np.bincount(state, weights=chosen != member, minlength=len(sizes))
    keep = (optimal > 0) & (sizes > 0) & (True if mask is None else mask)
    if not keep.any():
        return {"states": 0}
    precision = hits[keep] / np.maximum(predicted[keep], 1)
    recall = hits[keep] / optimal[keep]
    f1 = np.where(precision + recall > 0, 2 * precision * recall / np.maximum(precision + recall, 1e-12), 0.0)
    return {"states": int(keep.sum()), "predicted_size": float(predicted[keep].mean()),
            "optimal_size": float(optimal[keep].mean()),
            "size_ratio": float(predicted[keep].mean() / optimal[keep].mean()),
            "precision": float(precision.mean()), "recall": float(recall.mean()), "f1": float(f1.mean()),
            "exact": float(np.mean(wrong[keep] == 0))}


SIZE_RANGE = (0.8, 1.25)  # mean predicted size / mean optimal size a chosen threshold keeps


def choose_threshold(probabilities: np.ndarray, data: CoverRows) -> tuple[float, list[dict]]:
    """The threshold of ``THRESHOLDS`` with the highest mean per-state F1 on ``data`` (validation
    states) among those whose mean set size is within ``SIZE_RANGE`` of the optimum's (a plan much
    larger than the cover travels for nothing; F1 alone is flat over a wide range and picks sets
    half as large again), else the one whose size is nearest the optimum's; and every threshold's
    quality."""
    table = []
    for threshold in THRESHOLDS:
        chosen = predicted_sets(probabilities, data.rows.sizes, float(threshold))
        table.append({"threshold": float(threshold)} | set_quality(chosen, data.member, data.rows.sizes, data.optimal))
    rows = [row for row in table if row.get("states")]
    if not rows:
        return 0.5, table
    sized = [row for row in rows if SIZE_RANGE[0] <= row["size_ratio"] <= SIZE_RANGE[1]]
    best = (max(sized, key=lambda row: (row["f1"], -row["threshold"])) if sized
            else min(rows, key=lambda row: (abs(np.log(max(row["size_ratio"], 1e-9))), row["threshold"])))
    return best["threshold"], table


class CoverModel:
    """A trained ``cover-gbm``: ``probabilities(features) -> (V,)`` of (V, F) rows, and
    ``view_probabilities`` from a state; its sets are ``expected_sets`` (``threshold``: the best
    single threshold on validation, recorded for comparison)."""

    kind = "cover-gbm"

    def __init__(self, booster, rays: tuple[int, int], scene: dict, threshold: float, training: dict,
                 features: list[str] = BASE):
        self.booster, self.rays, self.scene, self.threshold, self.training = booster, tuple(rays), scene, threshold, training
        self.features = list(features)
        self.columns = np.array([FEATURES.index(name) for name in self.features], dtype=np.int64)
        self.path: Path | None = None

    def probabilities(self, features: np.ndarray) -> np.ndarray:
        """(V,) probabilities of (V, F) rows of its own columns (``features``)."""
        features = np.asarray(features, dtype=np.float32)
        if not len(features):
            return np.zeros(0)
        return np.asarray(self.booster.predict(features, num_threads=1), dtype=np.float64)

    def view_probabilities(self, probabilities: np.ndarray, scanned: np.ndarray, views: ViewSet,
                           config: SimConfig) -> np.ndarray:
        """(V,) each of ``views``' probability of being in the cover of the state of the (n, n, n)
        grid after scans from ``scanned`` (P, 3) positions."""
        features = view_features(probabilities, scanned, bundle_for(views, config, self.rays))
        return self.probabilities(features[:, self.columns])

    def check_scene(self, config: SimConfig, where: str) -> None:
        """ConfigError when ``config``'s grid is not the one the model was trained on."""
        check_grid(self.scene, config, where, "a cover model")

    def view_set_warning(self, config: SimConfig, where: str) -> str | None:
        """A line when ``config``'s candidate views are none of the view sets the model was trained on
        (``training["view_sets"]``, ``nbvtrain.ranking.rankdata.layout_label``): its sets there may be far
        from the cover's size (trained on SCVP's 32 alone, it planned 164 of the paper's 500 views);
        None when they are one of them, or the file records none (written before it did)."""
        from nbvtrain.ranking.rankdata import layout_label

        trained = self.training.get("view_sets")
        here = layout_label(config)
        if not trained or here in trained:
            return None
        return (f"{where}: a cover model trained on {', '.join(trained)} only, planning on {here}: its sets may be far "
                "from a cover's size there; fit one on this view set too (docs/setcover.md)")

    def save(self, path: Path) -> None:
        from nbvtrain.ranking._lightgbm import TEXT_KEY, text_digest

        model = self.booster.model_to_string()
        head = {"format": FORMAT, "format_version": FORMAT_VERSION, "kind": self.kind, "features": self.features,
                "rays": list(self.rays), "scene": self.scene, "threshold": self.threshold, "training": self.training,
                TEXT_KEY: text_digest(model), "lightgbm": model}
        write_atomic(Path(path), json.dumps(head, indent=1, allow_nan=False))


def load_cover_model(path: str | Path) -> CoverModel:
    """The ``cover-gbm`` model in ``path``; CheckpointError naming the file and the fix for anything else
    (a damaged LightGBM text included: ``nbvtrain.ranking._lightgbm.load_booster``)."""
    from nbvtrain.ranking._lightgbm import load_booster, read_model_json

    path = Path(path)
    head = read_model_json(path, "a cover model", USE_FIT, CheckpointError)
    if not isinstance(head, dict) or head.get("format") != FORMAT or head.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(f"{path}: not a cover model of format {FORMAT!r} {FORMAT_VERSION}; {USE_FIT}")
    missing = [key for key in ("features", "rays", "scene", "threshold", "training", "lightgbm") if key not in head]
    if missing:
        raise CheckpointError(f"{path}: not a cover model (no {', '.join(missing)}); {USE_FIT}")
    unknown = [name for name in head["features"] if name not in FEATURES] if isinstance(head["features"], list) \
        else ["(not a list)"]
    if unknown:
        raise CheckpointError(f"{path}: a cover model of other features ({', '.join(map(str, unknown[:3]))} are none "
                              f"of this nbvtrain's {len(FEATURES)} columns); retrain it with nbvtrain fit --model "
                              "cover-gbm")
    booster = load_booster(head, path, USE_FIT, CheckpointError)
    if booster.num_feature() != len(head["features"]):
        raise CheckpointError(f"{path}: its LightGBM model reads {booster.num_feature()} features, the file names "
                              f"{len(head['features'])}; {USE_FIT}")
    model = CoverModel(booster, tuple(head["rays"]), head["scene"], float(head["threshold"]), head["training"],
                       head["features"])
    model.path = path
    return model


def fit_cover_model(items: list[Path], config: CoverModelConfig, out: Path, root: Path | None = None,
                    workers: int = 2, cache: Path | None = None, progress: bool = False) -> dict:
    """Train ``cover-gbm`` on the covers of ``items`` (manifests or shard folders, any layouts; the
    split of ``nbvtrain.ranking.rankdata.sources_parts``) into ``out``: ``cover.json`` and ``metrics.json``
    (validation quality overall, per layout and per scan step, every threshold's); returns the metrics."""
    from nbvtrain.ranking._lightgbm import lightgbm
    from nbvtrain.ranking.rankdata import finite, grid_scene, sources_parts

    started = time.perf_counter()
    train_parts, val_parts, records = sources_parts(items, root, seed=config.seed)
    train = cover_rows(train_parts, config, config.sample, cache, workers, progress, "train")
    val = cover_rows(val_parts, config, 0, cache, workers, progress, "val")
    featured = time.perf_counter()
    params = {"objective": "binary", "metric": "binary_logloss", "learning_rate": config.learning_rate,
              "num_leaves": config.leaves, "min_data_in_leaf": config.min_rows, "feature_fraction": 0.9,
              "num_threads": config.threads, "deterministic": True, "force_row_wise": True, "seed": config.seed,
              "verbosity": -1}
    columns = [FEATURES.index(name) for name in BASE]
    train_set = lightgbm.Dataset(train.rows.features[:, columns], label=train.member.astype(np.int32),
                                 feature_name=list(BASE), free_raw_data=False)
    val_set = lightgbm.Dataset(val.rows.features[:, columns], label=val.member.astype(np.int32), reference=train_set)
    booster = lightgbm.train(params, train_set, num_boost_round=config.trees, valid_sets=[val_set],
                             valid_names=["val"], callbacks=[lightgbm.early_stopping(config.patience, verbose=False)])
    best = booster.best_iteration or booster.current_iteration()
    booster = lightgbm.Booster(model_str=booster.model_to_string(num_iteration=best))
    model = CoverModel(booster, config.rays, grid_scene(train_parts[0].path), 0.5,
                       asdict(config) | {"rounds": best, "sources": records,
                                         "view_sets": sorted(set(train.rows.layouts.tolist()))})
    probabilities = model.probabilities(val.rows.features[:, columns])
    model.threshold, table = choose_threshold(probabilities, val)
    out.mkdir(parents=True, exist_ok=True)
    model.save(out / "cover.json")
    chosen = expected_sets(probabilities, val.rows.sizes)
    layouts, steps = val.rows.layouts, val.rows.steps
    metrics = {"model": "cover-gbm", "file": "cover.json", "rule": "expected size", "threshold": model.threshold,
               "rounds": best,
               "val": set_quality(chosen, val.member, val.rows.sizes, val.optimal),
               "val_at_threshold": set_quality(predicted_sets(probabilities, val.rows.sizes, model.threshold),
                                               val.member, val.rows.sizes, val.optimal),
               "per_layout": {layout: set_quality(chosen, val.member, val.rows.sizes, val.optimal, layouts == layout)
                              for layout in sorted(set(layouts.tolist()))},
               "per_step": {int(step): set_quality(chosen, val.member, val.rows.sizes, val.optimal, steps == step)
                            for step in np.unique(steps) if step <= 10},
               "thresholds": table, "proved_share": float(np.concatenate([train.proved, val.proved]).mean()),
               "train_states": len(train.rows), "train_rows": int(len(train.member)), "val_states": len(val.rows),
               "val_rows": int(len(val.member)), "feature_seconds": round(featured - started, 1),
               "model_seconds": round(time.perf_counter() - featured, 1), "sources": records}
    (out / "metrics.json").write_text(json.dumps(finite(metrics), indent=1, allow_nan=False) + "\n")
    return metrics
