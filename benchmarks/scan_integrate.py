"""Benchmark: one 176 x 144 scan cast and integrated into the 32^3 grid, next to OctoMap.

For each mesh, scans from random views of the default hemisphere are cast (open3d) and
integrated (nbvdata.grid); the same scans then go through OctoMap's insertPointCloud
(pyoctomap) in a second pass of the same process. Times are medians over all scans; the ratio is the headline figure.

    python benchmarks/scan_integrate.py [--scans 40] [--threads 2]

Target: cast + integrate <= 5 ms median on a 2-core machine.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numba
import numpy as np

from nbvdata.config import SimConfig
from nbvdata.grid import OccupancyGrid
from nbvdata.mesh import load_mesh
from nbvdata.sensor import MeshScanner
from nbvdata.shapes import builtin_object
from nbvdata.views import view_sphere

SHARED_MESHES = Path(__file__).resolve().parents[2] / "shared" / "meshes"
MESHES = ["test/bunny_hr__odedstein.obj", "test/teapot__alecjacobson.obj", "test/armadillo_remeshed__odedstein.obj",
          "train/drill__ycb_urdfmodels.obj", "train/desk_lamp__sh3d_blendswap_cc0.ply"]


def _objects(config: SimConfig) -> list:
    if SHARED_MESHES.is_dir():
        return [load_mesh(SHARED_MESHES / name, config.mesh) for name in MESHES]
    print(f"{SHARED_MESHES} absent: benchmarking the built-in shapes instead")
    return [builtin_object(name, config.mesh) for name in ("mug", "table_lamp", "snowman")]


def _median_ms(samples: list[float]) -> float:
    return 1e3 * statistics.median(samples)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=40, help="scans per mesh")
    parser.add_argument("--threads", type=int, default=numba.config.NUMBA_NUM_THREADS, help="numba threads")
    args = parser.parse_args()
    numba.set_num_threads(args.threads)
    try:
        import pyoctomap
    except ImportError:
        pyoctomap = None
        print("pyoctomap not installed (pip install pyoctomap): OctoMap column left empty")

    config = SimConfig()
    views = view_sphere(config.views)
    rng = np.random.default_rng(0)
    # warm-up: compile the kernels before timing
    warm = MeshScanner(builtin_object("mug").mesh, config.sensor)
    OccupancyGrid(config.scene_grid).integrate(warm.scan(views[0]), config.sensor.far)

    print(f"{'mesh':42s} {'faces':>7s} {'cast':>7s} {'integr':>7s} {'total':>7s} {'octomap':>8s} {'speedup':>8s}  (ms, median of {args.scans})")
    totals, octomaps = [], []
    for obj in _objects(config):
        scanner = MeshScanner(obj.mesh, config.sensor)
        grid = OccupancyGrid(config.scene_grid)
        tree = pyoctomap.OcTree(grid.resolution) if pyoctomap else None
        cast, integrate, total, octomap, scans = [], [], [], [], []
        for view in rng.choice(len(views), args.scans, replace=False):
            start = time.perf_counter()
            scan = scanner.scan(views[int(view)])
            middle = time.perf_counter()
            grid.integrate(scan, config.sensor.far)
            end = time.perf_counter()
            cast.append(middle - start)
            integrate.append(end - middle)
            total.append(end - start)
            scans.append(scan)
        # OctoMap in a second pass over the same scans, so neither disturbs the other's caches.
        for scan in scans if tree is not None else []:
            points, origin = scan.points.astype(np.float64), scan.origin.astype(np.float64)
            start = time.perf_counter()
            tree.insertPointCloud(points, origin, max_range=config.sensor.far)
            octomap.append(time.perf_counter() - start)
        totals += total
        octomaps += octomap
        octo = f"{_median_ms(octomap):8.1f}" if octomap else f"{'-':>8s}"
        ratio = f"{_median_ms(octomap) / _median_ms(total):7.1f}x" if octomap else f"{'-':>8s}"
        print(f"{obj.source[:42]:42s} {len(obj.mesh.faces):7d} {_median_ms(cast):7.2f} {_median_ms(integrate):7.2f} "
              f"{_median_ms(total):7.2f} {octo} {ratio}")
    summary = f"all meshes: cast+integrate median {_median_ms(totals):.2f} ms (target <= 5 ms)"
    if octomaps:
        summary += f", OctoMap insertPointCloud {_median_ms(octomaps):.1f} ms, {_median_ms(octomaps) / _median_ms(totals):.1f}x faster"
    print(summary + f"; numba threads: {numba.get_num_threads()}")


if __name__ == "__main__":
    main()
