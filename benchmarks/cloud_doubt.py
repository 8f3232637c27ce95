"""How many cloud points would another CPU's Embree move? A stand-in for a second CPU, measured.

Which triangle a ray meets first, and whether it meets one at all where it grazes an outline, is
Embree's float32 decision, which another instruction set may make otherwise within its doubt.
This casts every ray of the candidate views twice: as it is and nudged by up to ``--ulps`` units
in the last place in each float32 component (about Embree's doubt; the outline rule's second
casts are nudged too), and counts the rays whose answer changes:

- reported: the distance to the reported triangle's plane, over the rays that hit both times
  (what a cloud would hold without a canonical rule - the baseline, in the same run),
- hit/miss: rays that hit on one cast and miss (or leave the sensor's range) on the other -
  grazed open edges and silhouettes (also the baseline),
- cloud: the clouds' distance (``MeshScanner._cloud_distances``: the canonical triangle, outlines
  passed through), a point on one cast and none on the other included - what a second CPU could
  still move.

    python benchmarks/cloud_doubt.py ../shared/meshes/train/desk_lamp2__sh3d_scopia.ply [--ulps 2] [--views 500]

Target: cloud 0 (the rules cover every tie of two surfaces and every grazed outline).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from nbvdata.core.config import SimConfig, ViewConfig
from nbvdata.core.views import view_sphere
from nbvdata.simulation.mesh import load_mesh
from nbvdata.simulation.sensor import MeshScanner, plane_distances


def nudge(rays: np.ndarray, ulps: int, rng: np.random.Generator) -> np.ndarray:
    """``rays`` (M, 6) float32 with each component moved by up to ``ulps`` ulps, at random."""
    out = rays.copy()
    for _ in range(ulps):
        step = rng.integers(-1, 2, size=out.shape)
        out = np.where(step > 0, np.nextafter(out, np.float32(np.inf)),
                       np.where(step < 0, np.nextafter(out, np.float32(-np.inf)), out))
    return out


def census(path: Path, config: SimConfig, ulps: int, seed: int) -> dict[str, int]:
    """Counts of rays cast, reassigned, and changed in each way (see the module's docstring)."""
    scanner = MeshScanner(load_mesh(path, config.mesh).mesh, config.sensor, threads=1)
    vertices, faces = scanner._vertices, scanner._faces
    near, far = config.sensor.near, config.sensor.far
    rng = np.random.default_rng(seed)
    embree = scanner._triangles
    counts = dict.fromkeys(("rays", "reassigned", "reported", "hit/miss", "cloud"), 0)
    for positions, rotations in scanner._batches(view_sphere(config.views)):
        rays, cast, triangles, t_cast = scanner._distances(positions, rotations)
        others = embree(nudge(rays[cast], ulps, rng))
        t_other = np.empty(len(cast))
        plane_distances(rays, cast, others, vertices, faces, t_other)
        cloud = scanner._cloud_distances(rays, cast, triangles, t_cast)
        scanner._triangles = lambda some: embree(nudge(some, ulps, rng))  # the second casts too
        try:
            cloud_other = scanner._cloud_distances(rays, cast, others, t_other)
        finally:
            scanner._triangles = embree
        hit, hit_other = (t_cast >= near) & (t_cast <= far), (t_other >= near) & (t_other <= far)
        kept, kept_other = (cloud >= near) & (cloud <= far), (cloud_other >= near) & (cloud_other <= far)
        counts["rays"] += len(cast)
        counts["reassigned"] += int(np.count_nonzero(triangles != others))
        counts["reported"] += int(np.count_nonzero(hit & hit_other & (t_cast != t_other)))
        counts["hit/miss"] += int(np.count_nonzero(hit != hit_other))
        counts["cloud"] += int(np.count_nonzero((kept != kept_other) | (kept & (cloud != cloud_other))))
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("meshes", nargs="+", type=Path)
    parser.add_argument("--ulps", type=int, default=2, help="nudge each ray component by up to this many ulps")
    parser.add_argument("--views", type=int, default=500, help="candidate views of the default sphere")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    config = SimConfig(views=ViewConfig(count=args.views))
    print(f"{'mesh':40s} {'rays':>9s} {'reassigned':>10s} {'reported':>9s} {'hit/miss':>8s} {'cloud':>6s} {'s':>6s}")
    for path in args.meshes:
        start = time.perf_counter()
        c = census(path, config, args.ulps, args.seed)
        print(f"{path.name[:40]:40s} {c['rays']:9d} {c['reassigned']:10d} {c['reported']:9d} {c['hit/miss']:8d} "
              f"{c['cloud']:6d} {time.perf_counter() - start:6.1f}")
    print("reported: the reported triangle's distance changed (no rule, rays that hit both times); hit/miss: "
          "a hit one time, none the other; cloud: the clouds' point moved, appeared or vanished")


if __name__ == "__main__":
    main()
