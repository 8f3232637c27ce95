"""Benchmark: what the partial point clouds (``state.points``) cost, and the FPS that makes them.

1. Farthest-point sampling of real accumulated clouds (the hits of 1 to 10 scans of the first
   meshes): ``nbvdata.core.cloud.farthest_points`` against the plain O(N M) loop it must equal index for
   index, and against the FPS of other packages when they are installed (fpsample, open3d), with
   whether each gives the same indices.
2. ``nbvdata generate`` on a folder of meshes with the default settings and with
   ``--set state.points=N``, each job in a fresh process (``benchmarks/generate_folder.py``'s job),
   the two alternating (A B B A ...) ``--repeats`` times: medians of the wall times and their
   ratio, and where the workers' time went.

    nice python benchmarks/points.py [--meshes ../shared/meshes/train] [--limit 0] [--workers 2]
        [--repeats 3] [--points 1024] [--skip-generate]

Target (issue 25): the whole train/ folder with state.points=1024 in <= 1.3x the default's time.
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TRAIN = ROOT.parent / "shared" / "meshes" / "train"


def _folder_job():
    """``benchmarks/generate_folder.py`` as a module (its ``_job`` and ``_print``)."""
    spec = importlib.util.spec_from_file_location("generate_folder", ROOT / "benchmarks" / "generate_folder.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _best(function, repeats: int = 5) -> float:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        function()
        times.append(time.perf_counter() - started)
    return 1e3 * min(times)


def fps_table(meshes: Path, points: int) -> None:
    import numba

    from nbvdata.core.cloud import ScannedCloud, farthest_points, farthest_points_reference
    from nbvdata.core.config import SimConfig
    from nbvdata.core.views import view_sphere
    from nbvdata.simulation.sensor import MeshScanner
    from nbvdata.simulation.sources import mesh_sources

    numba.set_num_threads(1)
    others = {}
    try:
        import fpsample

        others["fpsample bucket_fps_kdline (h=5)"] = lambda c, n: fpsample.bucket_fps_kdline_sampling(c, n, h=5,
                                                                                                     start_idx=0)
        others["fpsample fps_sampling"] = lambda c, n: fpsample.fps_sampling(c, n, start_idx=0)
    except ImportError:
        print("fpsample: not installed (pip install fpsample: its latest release is a source package that needs "
              "a Rust toolchain; 0.3.3 has wheels for CPython 3.10-3.12)")
    from nbvdata.simulation._open3d import open3d as o3d

    def open3d_fps(cloud: np.ndarray, n: int) -> np.ndarray:
        cloud64 = cloud.astype(np.float64)
        picked = np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud64))
                            .farthest_point_down_sample(n, 0).points)
        index = {row.tobytes(): i for i, row in enumerate(cloud64)}
        return np.array([index.get(row.tobytes(), -1) for row in picked])
    others["open3d farthest_point_down_sample"] = open3d_fps

    sources, _ = mesh_sources(meshes)
    config = SimConfig()
    views = view_sphere(config.views)
    rng = np.random.default_rng(0)
    farthest_points(np.random.default_rng(0).random((100, 3)).astype(np.float32), 10)  # compile
    farthest_points_reference(np.random.default_rng(0).random((100, 3)).astype(np.float32), 10)
    print(f"\nFarthest-point sampling to {points} points, 1 thread, best of 5 (ms); '=' same indices as the plain loop")
    names = ["nbvdata.core.cloud", "plain loop (reference)", *others]
    print(f"{'mesh':24s} {'scans':>5s} {'points':>7s} " + " ".join(f"{name[:22]:>24s}" for name in names))
    for source in sources[:3]:
        scanner = MeshScanner(source.load(config.mesh).mesh, config.sensor, threads=1)
        cloud = ScannedCloud()
        for k, view in enumerate(rng.choice(len(views), 10, replace=False), start=1):
            cloud.add(scanner.scan(views[int(view)]).hit_points)
            if k not in (1, 3, 6, 10) or len(cloud) < points:
                continue
            scanned = cloud.points()
            reference = farthest_points_reference(scanned, points)
            cells = []
            for name in names:
                function = {"nbvdata.core.cloud": farthest_points,
                            "plain loop (reference)": farthest_points_reference}.get(name) or others[name]
                same = "=" if np.array_equal(np.asarray(function(scanned, points)), reference) else "x"
                cells.append(f"{_best(lambda: function(scanned, points), 2 if 'plain' in name else 5):22.2f} {same}")
            print(f"{source.stem[:24]:24s} {k:5d} {len(scanned):7d} " + " ".join(cells))


def generation(meshes: Path, limit: int, workers: int, repeats: int, points: int) -> None:
    folder = _folder_job()
    overrides = [f"generate.workers={workers}"]
    configs = {"default": overrides, f"state.points={points}": overrides + [f"state.points={points}"]}
    seconds: dict[str, list[float]] = {label: [] for label in configs}
    worker: dict[str, list[float]] = {label: [] for label in configs}
    reports: dict[str, dict] = {}
    print(f"\n{meshes}{f' (first {limit})' if limit else ''}, {workers} workers, {repeats} alternating repeats")
    with tempfile.TemporaryDirectory(prefix="nbv-points-") as tmp:
        for repeat in range(repeats):
            order = list(configs) if repeat % 2 == 0 else list(configs)[::-1]
            for label in order:
                report = folder._job(ROOT, meshes.resolve(), Path(tmp) / f"{repeat}-{label}", limit, configs[label])
                seconds[label].append(report["seconds"])
                worker[label].append(sum(report["phases"].values()))
                reports[label] = report
                print(f"  repeat {repeat + 1} {label}: {report['seconds']:.1f} s, {report['samples']:,} states")
    for label, report in reports.items():
        folder._print(f"{label} (last repeat)", report)
    medians = {label: statistics.median(values) for label, values in seconds.items()}
    base, clouds = medians["default"], medians[f"state.points={points}"]
    print(f"median wall time: default {base:.1f} s, state.points={points} {clouds:.1f} s: "
          f"{clouds / base:.2f}x (target <= 1.3x); per repeat: "
          + ", ".join(f"{b / a:.2f}x" for a, b in zip(seconds["default"], seconds[f"state.points={points}"])))
    busy = {label: statistics.median(values) for label, values in worker.items()}
    print(f"median worker time (all phases): default {busy['default']:.1f} s, state.points={points} "
          f"{busy[f'state.points={points}']:.1f} s: {busy[f'state.points={points}'] / busy['default']:.2f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--meshes", type=Path, default=TRAIN, help="folder, mesh file or .txt list")
    parser.add_argument("--limit", type=int, default=0, help="only the first N meshes (0 = all)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3, help="jobs of each configuration, alternating")
    parser.add_argument("--points", type=int, default=1024)
    parser.add_argument("--skip-generate", action="store_true", help="only the FPS table")
    args = parser.parse_args()
    if not args.meshes.exists():
        raise SystemExit(f"{args.meshes} absent: pass --meshes with a folder of meshes")
    fps_table(args.meshes, args.points)
    if not args.skip_generate:
        generation(args.meshes, args.limit, args.workers, args.repeats, args.points)


if __name__ == "__main__":
    main()
