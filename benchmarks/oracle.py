"""Benchmark: scoring every candidate view at a reconstruction state, next to re-simulating them.

For each mesh, reconstruction states are taken along oracle-labelled runs (1 to 4 scans from
random starts). At each state all candidate views are scored twice in the same process:
by ``ViewOracle.score`` (the precomputed bit matrix), and by re-simulating every candidate's
scan from scratch (cast, match to the reference points, count). Both must give the same NBV;
times are medians over the states and the ratio is the headline figure.

    python benchmarks/oracle.py [--views 1000] [--states 12] [--resim-states 3]

Target: >= 1,000 candidate views scored in <= 2 ms median per state on a 2-core machine.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from nbvdata.core.config import SimConfig, load_config
from nbvdata.simulation.episode import scene_rng
from nbvdata.simulation.mesh import load_mesh
from nbvdata.simulation.oracle import pack_bits
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.shapes import builtin_object

SHARED_MESHES = Path(__file__).resolve().parents[2] / "shared" / "meshes"
MESHES = ["train/toy_duck__trimesh_khronos.ply", "train/drill__ycb_urdfmodels.obj",
          "test/bunny_hr__odedstein.obj"]


def _objects(config: SimConfig) -> list:
    if SHARED_MESHES.is_dir():
        return [load_mesh(SHARED_MESHES / name, config.mesh) for name in MESHES]
    print(f"{SHARED_MESHES} absent: benchmarking the built-in shapes instead")
    return [builtin_object(name, config.mesh) for name in ("mug", "table_lamp", "snowman")]


def _states(scene: Scene, count: int, rng: np.random.Generator) -> list[list[int]]:
    """``count`` visited-view sequences of 1-4 scans, each continued along the oracle's NBVs."""
    states = []
    while len(states) < count:
        visited = [int(rng.integers(len(scene.views)))]
        for _ in range(int(rng.integers(0, 4))):
            covered = np.bitwise_or.reduce(scene.oracle.visible[visited], axis=0)
            nbv = scene.oracle.score(covered).best(scene.config.oracle.min_overlap)
            if nbv is None:
                break
            visited.append(nbv)
        states.append(visited)
    return states


def _resimulate(scene: Scene, visited: list[int]) -> int | None:
    """The NBV found the slow way: scan every candidate afresh and count what it would add."""
    coverage, scanner, views = scene.coverage, scene.scanner, scene.views
    covered = coverage.covered_by_scans(scanner.scan(views[v]) for v in visited)
    observable = coverage.observable.sum()
    best, best_gain = None, -1.0
    for v in range(len(views)):
        seen_by = coverage.covered_by(scanner.scan(views[v]).hit_points)
        size = np.count_nonzero(seen_by)
        overlap = np.count_nonzero(seen_by & covered) / size if size else 0.0
        new = np.count_nonzero(seen_by & ~covered)
        if overlap >= scene.config.oracle.min_overlap and new > 0 and new / observable > best_gain:
            best, best_gain = v, new / observable
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=1000, help="candidate views (hemisphere)")
    parser.add_argument("--states", type=int, default=12, help="states per mesh for the bit-matrix scoring")
    parser.add_argument("--resim-states", type=int, default=3, help="of those, states also re-simulated (slow)")
    parser.add_argument("--repeats", type=int, default=20, help="timed scorings per state (median)")
    args = parser.parse_args()
    config = load_config(SimConfig, None, [f"views.count={args.views}"])
    rng = np.random.default_rng(0)
    print(f"{args.views} views, {config.sensor.width}x{config.sensor.height} sensor, "
          f"{config.coverage.points} reference points")
    print(f"{'mesh':42s} {'build s':>8s} {'score ms':>9s} {'resim ms':>10s} {'speedup':>9s}")
    scores_ms, resim_ms = [], []
    for obj in _objects(config):
        start = time.perf_counter()
        scene = Scene.build(obj, config, scene_rng(0, obj.mesh_id))
        build = time.perf_counter() - start
        mesh_scores, mesh_resim = [], []
        for i, visited in enumerate(_states(scene, args.states, rng)):
            covered = pack_bits(scene.coverage.covered_by_scans(scene.scanner.scan(scene.views[v]) for v in visited))
            times = []
            for _ in range(args.repeats):
                start = time.perf_counter()
                nbv = scene.oracle.score(covered).best(config.oracle.min_overlap)
                times.append(time.perf_counter() - start)
            mesh_scores.append(statistics.median(times) * 1e3)
            if i < args.resim_states:
                start = time.perf_counter()
                slow = _resimulate(scene, visited)
                mesh_resim.append((time.perf_counter() - start) * 1e3)
                if slow != nbv:
                    raise SystemExit(f"{obj.source}: re-simulation chose view {slow}, the oracle {nbv}")
        scores_ms += mesh_scores
        resim_ms += mesh_resim
        score, resim = statistics.median(mesh_scores), statistics.median(mesh_resim)
        print(f"{obj.source[:42]:42s} {build:8.2f} {score:9.3f} {resim:10.0f} {resim / score:8.0f}x")
    score, resim = statistics.median(scores_ms), statistics.median(resim_ms)
    print(f"all meshes: {args.views} views scored in {score:.3f} ms median per state (target <= 2 ms); "
          f"re-simulation {resim / 1e3:.2f} s; {resim / score:,.0f}x faster, same NBV at every re-simulated state")


if __name__ == "__main__":
    main()
