"""``nbvtrain fit --model viewrank-gbm|viewrank-mlp``: a ranker trained on published versions.

Sources are manifests (``manifests/NAME-X.Y.Z.json``, each verified by size) or folders of
shards; several at once mix their view sets - the point of a ranker of any view set. One mesh
split holds for all of them (``nbvtrain.ranking.rankdata.sources_parts``): the first manifest's (its val meshes validate,
its test meshes are never read), else ``nbvdata.schema.manifest.mesh_split`` of the folders' meshes.

The features of every state are computed in ``workers`` processes (one shard at a time, each
process one thread; the rows do not depend on the number of workers) and kept in
``feature_cache`` (default ``runs/viewrank-features``), so a second model on the same shards
(the other kind, other settings of the model) reads them back instead of walking every grid again.

The run folder ``out`` holds the model (``viewrank.json`` or ``viewrank.pt``), ``metrics.json``
(validation gain ratios overall, per layout and per scan step, beside every single feature's and
``farthest``'s, the data's sizes and seconds), ``history.csv`` and ``config.yaml``.
"""

from __future__ import annotations

import csv
import fnmatch
import functools
import json
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import yaml

from nbvdata.core.config import ConfigError
from nbvdata.core.text import plural
from nbvdata.schema.shards import Shard
from nbvdata.simulation.viewfeatures import FEATURE_GROUPS
from nbvtrain.ranking.rankdata import (Part, RankingData, cache_path, cached_rows, concatenate, finite, grid_scene,
                                       sources_parts)
from nbvtrain.ranking.viewrank import RankerConfig, baseline_ratios, fit_gbm, fit_mlp

DEFAULT_CACHE = Path("runs") / "viewrank-features"


def part_rows(parts: list[Part], config: RankerConfig, sample: int, cache: Path | None, workers: int,
              progress: bool, what: str, prior: Path | None = None) -> RankingData:
    """The ranking rows of ``parts``, shard by shard in ``workers`` processes, in the order of ``parts``
    (``prior``: a surface prior's file, for the ``expected_surface`` columns)."""
    from joblib import Parallel, delayed
    from tqdm import tqdm

    def rows(part: Part) -> RankingData:
        return cached_rows(part.path, cache, config.rays, sample, config.seed, part.states, part.digest,
                           _prior(prior))

    bar = tqdm(total=len(parts), desc=f"features ({what})", unit="shard", disable=not progress, dynamic_ncols=True)
    if workers <= 1:
        out = []
        for part in parts:
            out.append(rows(part))
            bar.update()
    else:
        out = []
        for result in Parallel(n_jobs=workers, backend="loky", return_as="generator")(
                delayed(_rows_one_thread)(part, cache, config.rays, sample, config.seed, prior) for part in parts):
            out.append(result)
            bar.update()
    bar.close()
    return concatenate(out)


def _cached(part: Part, cache: Path | None, config: RankerConfig, sample: int, prior: Path | None = None) -> bool:
    """Whether ``part``'s rows lie in the feature cache already (then they are read, not computed)."""
    return cache is not None and part.digest is not None and cache_path(
        cache, part.digest, config.rays, sample, config.seed, part.states, _prior(prior)).is_file()


def _rows_one_thread(part: Part, cache: Path | None, rays: tuple[int, int], sample: int, seed: int,
                     prior: Path | None = None) -> RankingData:
    import numba

    numba.set_num_threads(1)
    return cached_rows(part.path, cache, rays, sample, seed, part.states, part.digest, _prior(prior))


@functools.lru_cache(maxsize=2)
def _prior(path: Path | None):
    """The surface prior of ``path``, loaded once per process (None: none)."""
    if path is None:
        return None
    from nbvtrain.ranking.surfaceprior import load_surface_prior

    return load_surface_prior(path)


def fit_ranker(items: list[Path], config: RankerConfig, out: Path, target: str = "valid", root: Path | None = None,
               workers: int = 2, cache: Path | None = DEFAULT_CACHE, progress: bool = False,
               prior: Path | None = None) -> dict:
    """Train a ranker on ``items`` (module docstring) into the run folder ``out``; returns the
    metrics written to ``out/metrics.json``. ``prior``: the surface prior (``surface.json``) a
    ranker of the ``surface`` group reads, carried in its file."""
    reads_surface = any(name in FEATURE_GROUPS["surface"] for name in config.columns)
    if reads_surface != (prior is not None):
        raise ConfigError("--features surface and --surface-prior FILE go together: the expected surface is the "
                          "prior's" if reads_surface else "--surface-prior: only a ranker of the surface group reads "
                          "it (--features ...,surface)")
    started = time.perf_counter()
    train_parts, val_parts, records = sources_parts(items, root, seed=config.seed)
    out.mkdir(parents=True, exist_ok=True)
    hits = sum(_cached(part, cache, config, sample, prior) for parts, sample in ((train_parts, config.sample),
                                                                                (val_parts, 0)) for part in parts)
    train = part_rows(train_parts, config, config.sample, cache, workers, progress, "train", prior).labelled(target)
    val = part_rows(val_parts, config, 0, cache, workers, progress, "val", prior).labelled(target)
    featured = time.perf_counter()
    scene = grid_scene(train_parts[0].path)
    weights = state_weights(train, train_parts, config.mesh_weights) if config.mesh_weights else None
    report = (fit_gbm if config.model == "viewrank-gbm" else fit_mlp)(train, val, config, scene, weights)
    report.ranker.prior = _prior(prior)
    path = out / ("viewrank.json" if config.model == "viewrank-gbm" else "viewrank.pt")
    report.ranker.training |= {"target": target, "sources": records}
    report.ranker.save(path)
    scores = report.ranker.scores(val.features[:, report.ranker.columns])
    by_step = {int(step): val.gain_ratio(scores, val.steps == step) for step in np.unique(val.steps)}
    metrics = {"model": config.model, "file": path.name, "target": target,
               "val_gain_ratio": report.val_gain_ratio, "per_layout": report.per_layout,
               "per_step": by_step, "baselines": baseline_ratios(val), "diagnosis": diagnosis(val, scores),
               "train_states": len(train), "train_rows": int(len(train.gains)), "val_states": len(val),
               "val_rows": int(len(val.gains)), "feature_seconds": round(featured - started, 1),
               "feature_cache_hits": [hits, len(train_parts) + len(val_parts)],
               "model_seconds": round(report.seconds, 1), "sources": records}
    (out / "metrics.json").write_text(json.dumps(finite(metrics), indent=1, allow_nan=False) + "\n")
    (out / "config.yaml").write_text(yaml.safe_dump({"ranker": _plain(asdict(config)), "target": target,
                                                     "sources": [str(item) for item in items]}, sort_keys=False))
    with (out / "history.csv").open("w", newline="") as handle:
        if report.history:
            writer = csv.DictWriter(handle, fieldnames=list(report.history[0]))
            writer.writeheader()
            writer.writerows(report.history)
    return metrics


def state_weights(data: RankingData, parts: list[Part], patterns: tuple[tuple[str, float], ...]) -> np.ndarray:
    """(S,) float64 each state's weight: that of the first (file-name pattern, weight) whose pattern
    (``fnmatch``) its mesh's source matches (the file name of a path), else 1; the sources are read
    from the shards' ``meshes`` attribute."""
    sources: dict[str, str] = {}
    for part in parts:
        with Shard(part.path) as shard:
            sources.update({mesh["id"]: Path(str(mesh["source"])).name for mesh in shard.info.meshes})

    def weight(mesh_id: str) -> float:
        source = sources.get(mesh_id, "")
        return next((float(w) for pattern, w in patterns if fnmatch.fnmatch(source, pattern)), 1.0)

    by_mesh = {mesh_id: weight(mesh_id) for mesh_id in np.unique(data.mesh_ids)}
    return np.array([by_mesh[mesh_id] for mesh_id in data.mesh_ids], dtype=np.float64)


def difficulty_thirds(data: RankingData) -> np.ndarray:
    """(S,) int 0, 1, 2: each state's mesh in the hardest, middle or easiest third of the meshes, by
    the mean observable coverage of its states after two scans (low: much surface still hidden
    after two views; the oracle-run analogue of the benchmark's split by the oracle's AUC)."""
    meshes, inverse = np.unique(data.mesh_ids, return_inverse=True)
    second = data.steps == 3
    coverage = np.array([data.coverage[(inverse == m) & second].mean() if ((inverse == m) & second).any()
                         else data.coverage[inverse == m].mean() for m in range(len(meshes))])
    order = np.argsort(coverage, kind="stable")
    third = np.empty(len(meshes), dtype=np.int64)
    third[order] = np.minimum(3 * np.arange(len(meshes)) // max(len(meshes), 1), 2)
    return third[inverse]


def diagnosis(data: RankingData, scores: np.ndarray | None = None) -> dict:
    """Where a ranker can win, on validation states: per scan step and per difficulty third the
    gain ratio of ``farthest``'s choice (1 - its top-1 regret against the oracle), of the best single
    feature there and of ``scores`` (a ranker's); and every feature's gain ratio alone."""
    from nbvdata.simulation.viewfeatures import FEATURES

    columns = {name: data.features[:, k].astype(np.float64) for k, name in enumerate(FEATURES)}
    signs = {name: 1.0 if data.gain_ratio(column) >= data.gain_ratio(-column) else -1.0
             for name, column in columns.items()}
    keep = (data.best > 0) & (data.sizes > 0)

    def row(mask: np.ndarray) -> dict:
        chosen = mask & keep
        singles = {name: data.gain_ratio(signs[name] * column, mask) for name, column in columns.items()}
        best = max(singles, key=lambda name: -np.inf if np.isnan(singles[name]) else singles[name])
        out = {"states": int(chosen.sum()),
               "farthest": float(np.mean(data.farthest[chosen] / data.best[chosen])) if chosen.any() else float("nan"),
               "best_feature": best, "best_feature_ratio": singles[best]}
        if scores is not None:
            out["ranker"] = data.gain_ratio(scores, mask)
        return out

    thirds = difficulty_thirds(data)
    return {"by_step": {int(step): row(data.steps == step) for step in np.unique(data.steps)},
            "by_third": {name: row(thirds == k) for k, name in enumerate(("hard", "medium", "easy"))},
            "by_layout": {layout: row(data.layouts == layout) for layout in sorted(set(data.layouts.tolist()))},
            "features": {name: data.gain_ratio(signs[name] * column) for name, column in columns.items()},
            "signs": signs}


def _plain(value):
    if isinstance(value, tuple):
        return [_plain(item) for item in value]
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    return value


def describe(metrics: dict) -> str:
    """A line on a fitted ranker."""
    layouts = ", ".join(f"{layout} {ratio:.3f}" for layout, ratio in metrics["per_layout"].items())
    far = metrics["baselines"].get("farthest (its own choice)", float("nan"))
    return (f"{metrics['model']}: validation gain ratio {metrics['val_gain_ratio']:.3f} (farthest {far:.3f}; "
            f"{layouts}) on {plural(metrics['val_states'], 'state')}, trained on "
            f"{plural(metrics['train_states'], 'state')}")
