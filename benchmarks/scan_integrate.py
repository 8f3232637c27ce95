"""Benchmark: one 176 x 144 scan cast and integrated into the 32^3 grid, against the code of
another git revision and against OctoMap.

For each mesh, scans from random views of the default hemisphere are cast (open3d) and
integrated (nbvdata.simulation.grid) by this checkout's code and by ``--baseline``'s (its sensor.py and
grid.py, loaded from git), alternating scan by scan; both must give the same points and the
same voxel updates. The first ``--octomap-scans`` scans then go through OctoMap's
insertPointCloud (pyoctomap) in a second pass of the same process. Times are medians.

    python benchmarks/scan_integrate.py [--scans 40] [--threads 2] [--baseline 62dc09d] [--no-clouds]

``--no-clouds`` casts this checkout's scans with ``cloud=False`` (what grid integration, coverage
and runs without clouds use); the baseline's scans are cast as its code casts them by default.

Target (issue 16): cast + integrate <= 5 ms median on a 2-core machine, voxel-identical to OctoMap.
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

from nbvdata.core.config import SimConfig
from nbvdata.core.views import view_sphere
from nbvdata.simulation.grid import OccupancyGrid
from nbvdata.simulation.mesh import load_mesh
from nbvdata.simulation.sensor import MeshScanner
from nbvdata.simulation.shapes import builtin_object

ROOT = Path(__file__).resolve().parents[1]
SHARED_MESHES = ROOT.parent / "shared" / "meshes"
MESHES = ["test/bunny_hr__odedstein.obj", "test/teapot__alecjacobson.obj", "test/armadillo_remeshed__odedstein.obj",
          "train/drill__ycb_urdfmodels.obj", "train/desk_lamp__sh3d_blendswap_cc0.ply"]
BASELINE = "62dc09d"  # the code before the work on issue 16


def _objects(config: SimConfig) -> list:
    if SHARED_MESHES.is_dir():
        return [load_mesh(SHARED_MESHES / name, config.mesh) for name in MESHES]
    print(f"{SHARED_MESHES} absent: benchmarking the built-in shapes instead")
    return [builtin_object(name, config.mesh) for name in ("mug", "table_lamp", "snowman")]


def _baseline_module(revision: str, name: str, folder: Path):
    """nbvdata/<name>.py as it was at ``revision``, imported as ``baseline_<name>``."""
    shown = subprocess.run(["git", "-C", str(ROOT), "show", f"{revision}:nbvdata/{name}.py"],
                           capture_output=True, text=True)
    if shown.returncode != 0:
        raise SystemExit(f"cannot read nbvdata/{name}.py at {revision} ({shown.stderr.strip()}): pass --baseline "
                         "with a revision of this clone (a shallow clone lacks the old ones: git fetch --unshallow)")
    source = shown.stdout
    path = folder / f"baseline_{name}.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location(f"baseline_{name}", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def _ms(samples: list[float]) -> float:
    return 1e3 * statistics.median(samples)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=40, help="scans per mesh")
    parser.add_argument("--threads", type=int, default=numba.config.NUMBA_NUM_THREADS, help="numba threads")
    parser.add_argument("--baseline", default=BASELINE, help="git revision to compare against")
    parser.add_argument("--octomap-scans", type=int, default=5, help="scans per mesh through OctoMap (slow)")
    parser.add_argument("--no-clouds", dest="clouds", action="store_false",
                        help="this checkout's scans skip the clouds' canonical triangles (Scan.cloud None)")
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
    with tempfile.TemporaryDirectory() as folder:
        old_sensor = _baseline_module(args.baseline, "sensor", Path(folder))
        old_grid = _baseline_module(args.baseline, "grid", Path(folder))
        # warm-up: compile the kernels of both before timing
        for sensor, grid in ((old_sensor, old_grid), (sys.modules["nbvdata.simulation.sensor"], sys.modules["nbvdata.simulation.grid"])):
            scan = sensor.MeshScanner(builtin_object("mug").mesh, config.sensor).scan(views[0])
            grid.OccupancyGrid(config.scene_grid).integrate(scan, config.sensor.far)

        print(f"{'':30s} {'before (' + args.baseline + ')':>26s} {'after (this checkout)':>26s}")
        print(f"{'mesh':30s} {'cast':>8s} {'integr':>8s} {'total':>8s} {'cast':>8s} {'integr':>8s} {'total':>8s} "
              f"{'x':>5s} {'octomap':>8s} {'x':>6s}  (ms, medians)")
        before_all, after_all, octomap_all = [], [], []
        for obj in _objects(config):
            scanners = {"before": old_sensor.MeshScanner(obj.mesh, config.sensor),
                        "after": MeshScanner(obj.mesh, config.sensor)}
            grids = {"before": old_grid.OccupancyGrid(config.scene_grid), "after": OccupancyGrid(config.scene_grid)}
            times = {key: {"cast": [], "integrate": [], "total": []} for key in scanners}
            scans = []
            for view in rng.choice(len(views), args.scans, replace=False):
                cast, updates = {}, {}
                for key in ("before", "after"):
                    start = time.perf_counter()
                    if key == "after" and not args.clouds:
                        cast[key] = scanners[key].scan(views[int(view)], cloud=False)
                    else:
                        cast[key] = scanners[key].scan(views[int(view)])
                    middle = time.perf_counter()
                    updates[key] = grids[key].scan_update(cast[key], config.sensor.far)
                    grids[key].apply(updates[key])
                    end = time.perf_counter()
                    for phase, seconds in (("cast", middle - start), ("integrate", end - middle), ("total", end - start)):
                        times[key][phase].append(seconds)
                scans.append(cast["after"])
                if not (np.array_equal(cast["before"].points, cast["after"].points)
                        and np.array_equal(cast["before"].hit, cast["after"].hit)):
                    raise SystemExit(f"{obj.source}: view {view} gives another scan than the baseline's")
                if not (np.array_equal(updates["before"].free, updates["after"].free)
                        and np.array_equal(updates["before"].occupied, updates["after"].occupied)):
                    raise SystemExit(f"{obj.source}: view {view} gives another grid update than the baseline's")
            if not np.array_equal(grids["before"].log_odds, grids["after"].log_odds):
                raise SystemExit(f"{obj.source}: the grids differ from the baseline's")
            octomap = []
            if pyoctomap is not None:
                tree = pyoctomap.OcTree(grids["after"].resolution)
                for scan in scans[:args.octomap_scans]:
                    points, origin = scan.points.astype(np.float64), scan.origin.astype(np.float64)
                    start = time.perf_counter()
                    tree.insertPointCloud(points, origin, max_range=config.sensor.far)
                    octomap.append(time.perf_counter() - start)
            before_all += times["before"]["total"]
            after_all += times["after"]["total"]
            octomap_all += octomap
            b, a = times["before"], times["after"]
            octo = f"{_ms(octomap):8.1f} {_ms(octomap) / _ms(a['total']):5.0f}x" if octomap else f"{'-':>8s} {'-':>6s}"
            print(f"{Path(obj.source).name[:30]:30s} {_ms(b['cast']):8.2f} {_ms(b['integrate']):8.2f} {_ms(b['total']):8.2f} "
                  f"{_ms(a['cast']):8.2f} {_ms(a['integrate']):8.2f} {_ms(a['total']):8.2f} "
                  f"{_ms(b['total']) / _ms(a['total']):4.2f}x {octo}")
    summary = (f"all meshes: cast+integrate median {_ms(after_all):.2f} ms (target <= 5 ms), before {_ms(before_all):.2f} ms "
               f"({_ms(before_all) / _ms(after_all):.2f}x); the same scans and grid updates as before")
    if octomap_all:
        summary += (f"; OctoMap insertPointCloud {_ms(octomap_all):.0f} ms per scan, "
                    f"{_ms(octomap_all) / _ms(after_all):.0f}x slower")
    print(summary + f"; numba threads: {numba.get_num_threads()}")


if __name__ == "__main__":
    main()
