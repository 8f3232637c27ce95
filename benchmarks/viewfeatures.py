"""Per-view features and the hand-crafted metrics: time per state on one core, and what a coarse
ray bundle changes against the sensor's full image.

Target (issue 56): every metric for 500 views from one walk of the grid in <= 20 ms per state on
one core, and the ranker (features and model) in <= 20 ms per decision. The ranker's features walk
16 x 12 rays per view, the metric planners 32 x 24 (``METRIC_BUNDLE``). Prints, for reconstruction
states of a shard folder (default: made here from the built-in shapes), the median milliseconds of
``view_features`` per state at several bundle sizes and of a ranker's whole decision (``--ranker``),
beside the paper's information-gain baseline (``InfoGainPlanner``: 20 views, every one of the
sensor's 176 x 144 rays) in the same process. Then, on ``--states`` sample states, each metric
of the coarse bundle against the same metric from the sensor's full image (176 x 144 rays per
view): the Spearman correlation over the views, how often the bundle's best view is the full
image's, and the full-image value of the bundle's choice as a share of the best.

    python benchmarks/viewfeatures.py [--shards DIR] [--states 12] [--repeats 20] [--bundle 16x12] [--ranker FILE]
"""

from __future__ import annotations

import argparse
import glob
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

from nbvdata.core.config import SimConfig
from nbvdata.core.views import ViewSet, view_sphere
from nbvdata.schema.shards import Shard, view_state
from nbvdata.simulation.viewfeatures import BUNDLE, FEATURES, METRIC_BUNDLE, METRICS, RayBundle, view_features
from nbvtrain.planners import InfoGainPlanner


def states(folder: Path, count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(grid, scanned positions) of ``count`` states spread over the shards of ``folder``."""
    found = []
    paths = sorted(glob.glob(str(folder / "*.h5")))
    for path in paths:
        with Shard(path) as shard:
            taken = view_state(shard["run"], shard["step"], shard["last_view"], len(shard["view_positions"]))
            grids, positions = shard.grids(), shard["view_positions"]
            for i in range(0, len(grids), max(1, len(grids) // 3)):
                found.append((grids[i], positions[taken[i]]))
    rng = np.random.default_rng(0)
    return [found[i] for i in sorted(rng.choice(len(found), size=min(count, len(found)), replace=False))]


def median_ms(call, items, repeats: int) -> float:
    for item in items[:3]:
        call(item)
    times = []
    for k in range(repeats):
        started = time.perf_counter()
        call(items[k % len(items)])
        times.append(time.perf_counter() - started)
    return 1e3 * float(np.median(times))


def full_image_bundles(views: ViewSet, config: SimConfig) -> list[RayBundle]:
    """Bundles of every ray of the sensor's image, 25 views each (all 500 at once would not fit)."""
    return [RayBundle.build(ViewSet(views.positions[start:start + 25], views.rotations[start:start + 25]),
                            config.scene_grid, config.sensor, config.sensor.width, config.sensor.height)
            for start in range(0, len(views), 25)]


def full_image_metrics(grid: np.ndarray, scanned: np.ndarray, bundles: list[RayBundle]) -> np.ndarray:
    """(V, len(METRICS)) the metrics from every ray of the sensor's image."""
    columns = [FEATURES.index(column) for column in METRICS.values()]
    return np.concatenate([view_features(grid, scanned, bundle)[:, columns] for bundle in bundles])


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1]) if ra.std() and rb.std() else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shards", type=Path, help="a folder of shards of the default scene (500 hemisphere views)")
    parser.add_argument("--states", type=int, default=12, help="sample states for the full-image comparison")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--bundle", default=f"{METRIC_BUNDLE[0]}x{METRIC_BUNDLE[1]}", help="the coarse bundle compared "
                        "with the full image, WIDTHxHEIGHT (default the metric planners')")
    parser.add_argument("--ranker", type=Path, help="a ranker file (nbvtrain fit --model viewrank-*): time its decisions")
    args = parser.parse_args()
    numba.set_num_threads(1)
    config = SimConfig()
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.shards
        if folder is None:
            folder = Path(tmp) / "shards"
            subprocess.run([sys.executable, "-m", "nbvdata", "generate", "--out", str(folder), "--runs-per-mesh", "2",
                            "--workers", "1", "--no-progress"], check=True, stdout=subprocess.DEVNULL)
        sample = states(folder, max(args.states, 12))
    views = view_sphere(config.views)
    print(f"{len(sample)} states, {len(views)} candidate views, one core\n")
    infogain = InfoGainPlanner(config.scene_grid, config.sensor, config.views.radius, config.mesh.object_size,
                               config.oracle.min_overlap)
    baseline = median_ms(lambda state: infogain.scores(state[0]), sample, args.repeats)
    print("| what | rays per view | ms per state (median) | x the baseline |\n|---|---|---|---|")
    print(f"| baseline: infogain, 20 views, full image | {config.sensor.width * config.sensor.height} | "
          f"{baseline:.1f} | 1.00 |")
    for width, height in ((8, 6), (12, 10), BUNDLE, (22, 18), METRIC_BUNDLE):
        bundle = RayBundle.build(views, config.scene_grid, config.sensor, width, height)
        ms = median_ms(lambda state: view_features(state[0], state[1], bundle), sample, args.repeats)
        mark = {BUNDLE: " (the ranker's)", METRIC_BUNDLE: " (the metric planners')"}.get((width, height), "")
        print(f"| every feature, 500 views{mark} | {width} x {height} | {ms:.1f} | {ms / baseline:.2f} |")
    if args.ranker is not None:
        from nbvtrain.ranking.viewrank import load_ranker

        ranker = load_ranker(args.ranker)
        ms = median_ms(lambda state: ranker.view_scores(state[0], state[1], views, config), sample, args.repeats)
        print(f"| {ranker.kind}: features and model, 500 views | {ranker.rays[0]} x {ranker.rays[1]} | {ms:.1f} | "
              f"{ms / baseline:.2f} |")

    coarse_size = tuple(int(part) for part in args.bundle.lower().split("x"))
    bundle = RayBundle.build(views, config.scene_grid, config.sensor, *coarse_size)
    columns = [FEATURES.index(column) for column in METRICS.values()]
    rho, same, share = {name: [] for name in METRICS}, {name: [] for name in METRICS}, {name: [] for name in METRICS}
    full_bundles = full_image_bundles(views, config)
    for grid, scanned in sample[:args.states]:
        coarse = view_features(grid, scanned, bundle)[:, columns]
        full = full_image_metrics(grid, scanned, full_bundles)
        for k, name in enumerate(METRICS):
            rho[name].append(spearman(coarse[:, k], full[:, k]))
            pick, best = int(np.argmax(coarse[:, k])), int(np.argmax(full[:, k]))
            same[name].append(pick == best)
            share[name].append(full[pick, k] / full[best, k] if full[best, k] > 0 else 1.0)
    print(f"\nThe {coarse_size[0]} x {coarse_size[1]} bundle against the full image ({config.sensor.width} x "
          f"{config.sensor.height} rays per view), {len(rho[next(iter(METRICS))])} states:\n")
    print("| metric | Spearman over the views (median) | same best view | full-image value of the bundle's choice |")
    print("|---|---|---|---|")
    for name in METRICS:
        print(f"| {name} | {np.nanmedian(rho[name]):.3f} | {100 * np.mean(same[name]):.0f} % | "
              f"{100 * np.mean(share[name]):.1f} % |")


if __name__ == "__main__":
    main()
