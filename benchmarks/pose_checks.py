"""What ``nbvtrain plan``'s pose checks (``nbvtrain.robot.sensordata.check_pose``) catch: simulated scans
of the built-in shapes from views all round, each given once with its camera-to-world pose (must
be accepted) and once with the inverse, world-to-camera, pose (should be refused), in two worlds
(object at the origin; object on a table at (0.6, -0.2, 0.75), turned), for clouds as a robot may
write them: a depth image's hits, with range noise, with the far points of rays without a return,
70 % of the points dropped at random, the left half of the image, and voxel-filtered (4 mm: no
longer on the pixel rays). Prints, per kind of cloud, how many correct poses were refused (must
be 0) and how many inverted ones each check caught, with the pixel-ray shares seen (the least
from a correct pose, the most from an inverted one; ``check_pose`` draws the line at 0.8) and
the largest share of points hidden behind others seen from a correct pose (refused from 0.02), then
the time of the check on a VGA-sized cloud, next to the time to read such a cloud (baseline,
same process).

    python benchmarks/pose_checks.py [--views 60] [--every 4] [--layout sphere] [--table-x 0.6]
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from nbvdata.core.config import SimConfig, ViewConfig
from nbvdata.core.views import view_sphere
from nbvdata.simulation.sensor import MeshScanner
from nbvdata.simulation.shapes import BUILTIN_SHAPES, builtin_object
from nbvtrain.robot.sensordata import SensorDataError, SensorScan, check_pose, hidden_share, pixel_ray_share, read_cloud

KINDS = ("hits", "noisy", "far points", "thinned", "half image", "voxel-filtered")
TABLE = np.eye(4)
TABLE[:3, :3] = Rotation.from_euler("zx", [37, 10], degrees=True).as_matrix()
TABLE[:3, 3] = [0.6, -0.2, 0.75]


def voxel_filter(points: np.ndarray, size: float) -> np.ndarray:
    """(M, 3) the centroids of the points in each voxel of side ``size`` (PCL's VoxelGrid)."""
    _, cell = np.unique(np.floor(points / size).astype(np.int64), axis=0, return_inverse=True)
    cell = cell.ravel()
    sums = np.zeros((cell.max() + 1, 3))
    np.add.at(sums, cell, points)
    return sums / np.bincount(cell)[:, None]


def cloud(kind: str, scan, rotation: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    points = (scan.points if kind == "far points" else scan.hit_points).astype(np.float64)
    if kind == "thinned":
        points = points[rng.random(len(points)) >= 0.7]
    elif kind == "half image":
        camera = (points - scan.origin) @ rotation.T
        points = points[camera[:, 0] < 0]
    elif kind == "voxel-filtered":
        points = voxel_filter(points, 0.004)
    return points


def verdict(points: np.ndarray, matrix: np.ndarray) -> str:
    try:
        check_pose(SensorScan(points, matrix, "scan"))
    except SensorDataError as error:
        text = str(error)
        return ("behind" if "lie behind the sensor" in text else "pixel rays" if "pixel rays" in text
                else "hidden points" if "hidden behind" in text else text)
    return "accepted"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--views", type=int, default=60, help="views all round the object")
    parser.add_argument("--every", type=int, default=4, help="scan from every n-th view")
    parser.add_argument("--layout", choices=["sphere", "hemisphere"], default="sphere",
                        help="views all round, or above the object only (the training data's)")
    parser.add_argument("--table-x", type=float, default=0.6, help="x of the table world's object, metres (how far "
                        "from the world origin: float32 clouds lose precision far out)")
    args = parser.parse_args()
    config = SimConfig()
    views = view_sphere(ViewConfig(count=args.views, layout=args.layout))
    TABLE[0, 3] = args.table_x
    rng = np.random.default_rng(0)
    print(f"{'cloud':15s} {'poses':>6s} {'correct refused':>16s} {'pixel rays: correct >=':>23s} {'inverted <=':>12s}"
          f" {'hidden: correct <=':>19s}  inverted: caught by ...")
    for kind in KINDS:
        sensor = dataclasses.replace(config.sensor, noise_std=0.002 if kind == "noisy" else 0.0)
        correct, inverted, shares, hidden = Counter(), Counter(), ([], []), []
        for shape in sorted(BUILTIN_SHAPES):
            scanner = MeshScanner(builtin_object(shape, config.mesh).mesh, sensor, threads=1)
            for index in range(0, len(views), args.every):
                pose = views[index]
                scan = scanner.scan(pose, rng if kind == "noisy" else None)
                points = cloud(kind, scan, pose.rotation, rng)
                if len(points) < 100:
                    continue
                matrix = np.eye(4)
                matrix[:3, :3], matrix[:3, 3] = pose.rotation.T, scan.origin
                for world in (np.eye(4), TABLE):
                    moved = (points @ world[:3, :3].T + world[:3, 3]).astype(np.float32).astype(np.float64)
                    for given, verdicts, seen in ((world @ matrix, correct, shares[0]),
                                                  (np.linalg.inv(world @ matrix), inverted, shares[1])):
                        verdicts[verdict(moved, given)] += 1
                        seen.append(pixel_ray_share(moved, given))
                    hidden.append(hidden_share(moved, (world @ matrix)[:3, 3]))
        total = sum(correct.values())
        caught = ", ".join(f"{name} {count}" for name, count in sorted(inverted.items()) if name != "accepted")
        print(f"{kind:15s} {total:6d} {total - correct['accepted']:16d} {min(shares[0]):23.3f} {max(shares[1]):12.3f}"
              f" {max(hidden):19.4f}  {caught}; missed {inverted['accepted']}")

    # Speed: a VGA depth image's worth of points (640 x 480), its own pose (the common, cheap case)
    # and an inverted one (every statistic), against reading the same cloud from a .npy file.
    scanner = MeshScanner(builtin_object("mug", config.mesh).mesh,
                          dataclasses.replace(config.sensor, width=640, height=480), threads=1)
    pose = views[5]
    scan = scanner.scan(pose)
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = pose.rotation.T, scan.origin
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "cloud.npy"
        np.save(path, scan.points)
        started = time.perf_counter()
        points = read_cloud(path)
        read = time.perf_counter() - started
    for name, given in (("its own pose", matrix), ("inverted pose", np.linalg.inv(matrix))):
        started = time.perf_counter()
        result = verdict(points, given)
        print(f"check_pose, {len(points)} points, {name}: {1e3 * (time.perf_counter() - started):.0f} ms ({result}); "
              f"reading the .npy cloud: {1e3 * read:.0f} ms")


if __name__ == "__main__":
    main()
