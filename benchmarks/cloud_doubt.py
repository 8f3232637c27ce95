"""How many cloud points would another CPU's Embree move? A stand-in for a second CPU, measured.

Which triangle a ray meets first is Embree's float32 decision, and another instruction set may
decide otherwise where two triangles are at the same depth within its doubt. This casts every
ray of the candidate views twice: as it is and nudged by up to ``--ulps`` units in the last place
in each float32 component (about Embree's doubt), and counts the rays whose answer changes:

- reported: the distance to the reported triangle's plane (what a cloud would hold without a
  canonical rule - the baseline, in the same run),
- canonical: the clouds' distance (``nbvdata.sensor._canonical_distances``): the rays a second
  CPU could still move,
- hit/miss: rays that hit on one cast and miss (or leave the sensor's range) on the other - a
  grazed open edge or silhouette, which no rule here covers.

    python benchmarks/cloud_doubt.py ../shared/meshes/train/desk_lamp2__sh3d_scopia.ply [--ulps 2] [--views 500]

Target: canonical changes only where hit/miss flips (the rule covers every tie of two surfaces).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from nbvdata.config import SimConfig, ViewConfig
from nbvdata.mesh import load_mesh
from nbvdata.sensor import MeshScanner, _canonical_distances, _plane_distances
from nbvdata.views import view_sphere


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
    vertices, faces, cells = scanner._vertices, scanner._faces, scanner.cells
    near, far = config.sensor.near, config.sensor.far
    rng = np.random.default_rng(seed)
    counts = dict.fromkeys(("rays", "reassigned", "reported", "canonical", "hit/miss"), 0)
    for positions, rotations in scanner._batches(view_sphere(config.views)):
        rays, cast, triangles, t_cast = scanner._distances(positions, rotations)
        others = scanner._triangles(nudge(rays[cast], ulps, rng))
        t_other = np.empty(len(cast))
        _plane_distances(rays, cast, others, vertices, faces, t_other)
        cloud, cloud_other = np.empty(len(cast)), np.empty(len(cast))
        _canonical_distances(rays, cast, triangles, t_cast, vertices, faces, *cells, cloud)
        _canonical_distances(rays, cast, others, t_other, vertices, faces, *cells, cloud_other)
        hit, hit_other = (t_cast >= near) & (t_cast <= far), (t_other >= near) & (t_other <= far)
        both = hit & hit_other
        counts["rays"] += len(cast)
        counts["reassigned"] += int(np.count_nonzero(triangles != others))
        counts["reported"] += int(np.count_nonzero(both & (t_cast != t_other)))
        counts["canonical"] += int(np.count_nonzero(both & (cloud != cloud_other)))
        counts["hit/miss"] += int(np.count_nonzero(hit != hit_other))
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("meshes", nargs="+", type=Path)
    parser.add_argument("--ulps", type=int, default=2, help="nudge each ray component by up to this many ulps")
    parser.add_argument("--views", type=int, default=500, help="candidate views of the default sphere")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    config = SimConfig(views=ViewConfig(count=args.views))
    print(f"{'mesh':40s} {'rays':>9s} {'reassigned':>10s} {'reported':>9s} {'canonical':>9s} {'hit/miss':>8s} {'s':>6s}")
    for path in args.meshes:
        start = time.perf_counter()
        c = census(path, config, args.ulps, args.seed)
        print(f"{path.name[:40]:40s} {c['rays']:9d} {c['reassigned']:10d} {c['reported']:9d} {c['canonical']:9d} "
              f"{c['hit/miss']:8d} {time.perf_counter() - start:6.1f}")
    print("reported: the reported triangle's distance changed (no canonical rule); canonical: the clouds' "
          "distance changed; both over the rays that hit on both casts")


if __name__ == "__main__":
    main()
