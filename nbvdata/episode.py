"""Simulated reconstructions labelled by exhaustive search: where the dataset's samples come from.

One run starts at a candidate view and repeats: scan, integrate, score every candidate view
(``nbvdata.oracle``), record the state with its next-best-view, move there. It stops after
``episode.max_scans`` scans (that last state is still recorded), or earlier when no valid view
would add ``episode.min_gain`` of the observable surface (that state has no label and is not
recorded).

With a noise-free sensor (the default) every scan comes from a fixed candidate view and is
deterministic, so a view's grid update and covered points are computed once per mesh and
reused (``ViewCache``): a run then costs a few array operations per state. With range noise
every scan is cast and integrated afresh, seeded by the run's seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nbvdata.grid import OccupancyGrid, ScanUpdate
from nbvdata.oracle import pack_bits, popcount
from nbvdata.scene import Scene
from nbvdata.views import Pose


class ViewCache:
    """Each candidate view's grid update, computed on the first visit (noise-free scans only)."""

    def __init__(self, scene: Scene):
        self.scene = scene
        self._updates: dict[int, ScanUpdate] = {}
        self._grid = scene.new_grid()  # scratch: only its marking buffers are used

    def update(self, view: int) -> ScanUpdate:
        if view not in self._updates:
            scan = self.scene.scanner.scan(self.scene.views[view])
            self._updates[view] = self._grid.scan_update(scan, self.scene.config.sensor.far)
        return self._updates[view]


class Reconstruction:
    """The state of one simulated reconstruction: the occupancy grid and the covered points.

    grid : OccupancyGrid
    covered : (W,) uint64 packed mask of the covered reference points (see ``nbvdata.oracle``)
    """

    def __init__(self, scene: Scene, cache: ViewCache | None, rng: np.random.Generator):
        """``cache`` None scans live (required when the sensor has range noise)."""
        self.scene = scene
        self.cache = cache
        self.rng = rng
        self.grid: OccupancyGrid = scene.new_grid()
        self.covered = np.zeros(scene.oracle.visible.shape[1], dtype=np.uint64)
        self.scans = 0

    def scan(self, view: int) -> None:
        """Scan from candidate ``view`` and integrate the scan."""
        if self.cache is not None:
            self.grid.apply(self.cache.update(view))
            self.covered |= self.scene.oracle.visible[view]
            self.scans += 1
        else:
            self.scan_pose(self.scene.views[view])

    def scan_pose(self, pose: Pose) -> np.ndarray:
        """Scan from any pose (a network's continuous prediction, say), cast live, and integrate;
        returns the (W,) packed reference points this scan covered.

        From a candidate view's pose with a noise-free sensor this gives the same grid and
        covered points as ``scan(view)``."""
        scan = self.scene.scanner.scan(pose, self.rng)
        self.scene.integrate(self.grid, scan)
        seen = pack_bits(self.scene.coverage.covered_by(scan.hit_points))
        self.covered |= seen
        self.scans += 1
        return seen


@dataclass
class RunRecord:
    """The labelled states of one run, one list entry per state (see ``nbvdata.shards``)."""

    log_odds: list[np.ndarray] = field(default_factory=list)
    nbv_index: list[int] = field(default_factory=list)
    gains: list[np.ndarray] = field(default_factory=list)
    overlaps: list[np.ndarray] = field(default_factory=list)
    coverage: list[tuple[float, float]] = field(default_factory=list)
    last_view: list[int] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.nbv_index)


def _mesh_key(seed: int, mesh_id: str) -> list[int]:
    return [seed, int(mesh_id[:16], 16)]


def scene_rng(seed: int, mesh_id: str) -> np.random.Generator:
    """The generator that draws a mesh's coverage reference points."""
    return np.random.default_rng(np.random.SeedSequence(_mesh_key(seed, mesh_id), spawn_key=(0,)))


def start_view(seed: int, mesh_id: str, view_count: int, run: int) -> int:
    """Start view of run ``run``: a seeded permutation of the views, so the first V runs differ."""
    order = np.random.default_rng(np.random.SeedSequence(_mesh_key(seed, mesh_id), spawn_key=(1,)))
    return int(order.permutation(view_count)[run % view_count])


def run_seed(seed: int, mesh_id: str, run: int) -> int:
    """Seed of run ``run``'s own generator (range noise), from the global seed and the mesh id."""
    sequence = np.random.SeedSequence(_mesh_key(seed, mesh_id), spawn_key=(2, run))
    return int(sequence.generate_state(1)[0])


def run_reconstruction(scene: Scene, start_view: int, rng: np.random.Generator,
                       cache: ViewCache | None) -> RunRecord:
    """One labelled run from ``start_view``; ``rng`` draws the range noise, if any."""
    config = scene.config
    oracle = scene.oracle
    record = RunRecord()
    state = Reconstruction(scene, cache, rng)
    state.scan(start_view)
    last = start_view
    while True:
        scores = oracle.score(state.covered)
        nbv = scores.best(config.oracle.min_overlap, config.episode.min_gain)
        if nbv is None:
            break
        record.log_odds.append(state.grid.log_odds.copy())
        record.nbv_index.append(nbv)
        record.gains.append(scores.gains.astype(np.float32))
        record.overlaps.append(scores.overlaps.astype(np.float32))
        record.coverage.append((oracle.observable_coverage(state.covered),
                                oracle.observable_coverage(state.covered | oracle.visible[nbv])))
        record.last_view.append(last)
        if state.scans >= config.episode.max_scans:
            break
        state.scan(nbv)
        last = nbv
    return record
