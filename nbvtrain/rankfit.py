"""``nbvtrain fit --model viewrank-gbm|viewrank-mlp``: a ranker trained on published versions.

Sources are manifests (``manifests/NAME-X.Y.Z.json``, each verified by size) or folders of
shards; several at once mix their view sets - the point of a ranker of any view set. One mesh
split holds for all of them (``sources_parts``): the first manifest's (its val meshes validate,
its test meshes are never read), else ``nbvdata.manifest.mesh_split`` of the folders' meshes.

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
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import yaml

from nbvdata.config import ConfigError
from nbvdata.files import shown_path
from nbvdata.manifest import mesh_split, open_verified
from nbvdata.shards import Shard, ShardError, shard_files
from nbvdata.text import plural
from nbvtrain.rankdata import RankingData, cache_path, cached_rows, concatenate
from nbvtrain.viewrank import RankerConfig, baseline_ratios, fit_gbm, fit_mlp

DEFAULT_CACHE = Path("runs") / "viewrank-features"


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
    are left out, every other mesh trains), or without a manifest ``nbvdata.manifest.mesh_split``
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


def part_rows(parts: list[Part], config: RankerConfig, sample: int, cache: Path | None, workers: int,
              progress: bool, what: str) -> RankingData:
    """The ranking rows of ``parts``, shard by shard in ``workers`` processes, in the order of ``parts``."""
    from joblib import Parallel, delayed
    from tqdm import tqdm

    def rows(part: Part) -> RankingData:
        return cached_rows(part.path, cache, config.rays, sample, config.seed, part.states, part.digest)

    bar = tqdm(total=len(parts), desc=f"features ({what})", unit="shard", disable=not progress, dynamic_ncols=True)
    if workers <= 1:
        out = []
        for part in parts:
            out.append(rows(part))
            bar.update()
    else:
        out = []
        for result in Parallel(n_jobs=workers, backend="loky", return_as="generator")(
                delayed(_rows_one_thread)(part, cache, config.rays, sample, config.seed) for part in parts):
            out.append(result)
            bar.update()
    bar.close()
    return concatenate(out)


def _cached(part: Part, cache: Path | None, config: RankerConfig, sample: int) -> bool:
    """Whether ``part``'s rows lie in the feature cache already (then they are read, not computed)."""
    return cache is not None and part.digest is not None and cache_path(cache, part.digest, config.rays, sample,
                                                                        config.seed, part.states).is_file()


def _rows_one_thread(part: Part, cache: Path | None, rays: tuple[int, int], sample: int, seed: int) -> RankingData:
    import numba

    numba.set_num_threads(1)
    return cached_rows(part.path, cache, rays, sample, seed, part.states, part.digest)


def fit_ranker(items: list[Path], config: RankerConfig, out: Path, target: str = "valid", root: Path | None = None,
               workers: int = 2, cache: Path | None = DEFAULT_CACHE, progress: bool = False) -> dict:
    """Train a ranker on ``items`` (module docstring) into the run folder ``out``; returns the
    metrics written to ``out/metrics.json``."""
    started = time.perf_counter()
    train_parts, val_parts, records = sources_parts(items, root, seed=config.seed)
    out.mkdir(parents=True, exist_ok=True)
    hits = sum(_cached(part, cache, config, sample) for parts, sample in ((train_parts, config.sample), (val_parts, 0))
               for part in parts)
    train = part_rows(train_parts, config, config.sample, cache, workers, progress, "train").labelled(target)
    val = part_rows(val_parts, config, 0, cache, workers, progress, "val").labelled(target)
    featured = time.perf_counter()
    scene = _scene(train_parts[0].path)
    report = (fit_gbm if config.model == "viewrank-gbm" else fit_mlp)(train, val, config, scene)
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
    (out / "metrics.json").write_text(json.dumps(_finite(metrics), indent=1, allow_nan=False) + "\n")
    (out / "config.yaml").write_text(yaml.safe_dump({"ranker": _plain(asdict(config)), "target": target,
                                                     "sources": [str(item) for item in items]}, sort_keys=False))
    with (out / "history.csv").open("w", newline="") as handle:
        if report.history:
            writer = csv.DictWriter(handle, fieldnames=list(report.history[0]))
            writer.writeheader()
            writer.writerows(report.history)
    return metrics


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
    from nbvdata.viewfeatures import FEATURES

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


def _scene(path: Path) -> dict:
    """The grid of a shard's scene: {grid_size, grid_extent} (metres)."""
    from nbvdata.config import SimConfig, from_dict

    with Shard(path) as shard:
        grid = from_dict(SimConfig, shard.info.config or {}).scene_grid
    return {"grid_size": grid.size, "grid_extent": round(float(grid.extent), 9)}


def _finite(value):
    """``value`` with every NaN or infinite float as None (JSON has no NaN): a gain ratio of no state."""
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(item) for item in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


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
