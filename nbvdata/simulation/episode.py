"""Simulated reconstructions labelled by exhaustive search: where the dataset's samples come from.

One run starts at a candidate view and repeats: scan, integrate, score every candidate view
(``nbvdata.simulation.oracle``), record the state with its next-best-view, move there. It stops after
``episode.max_scans`` scans (that last state is still recorded), or earlier when no valid view
would add ``episode.min_gain`` of the observable surface (that state has no label and is not
recorded).

With a noise-free sensor (the default) every scan comes from a fixed candidate view and is
deterministic, so a view's grid update and covered points are computed once per mesh and
reused (``ViewCache``): a run then costs a few array operations per state. With range noise
every scan is cast and integrated afresh, seeded by the run's seed.

A run may also leave the oracle's path, to reach the states a learned planner reaches (a
``Mover``): with probability ``episode.explore`` a move goes to a uniformly random valid view,
and with a policy (``nbvdata.simulation.policy``) the moves are the policy's, mixed with the oracle's by
``episode.oracle_mix``. The labels stay exact: every state is still scored exhaustively. A
policy's pose that is no candidate view is scanned live, whatever the sensor.

With ``state.points`` > 0 each recorded state also holds its partial point cloud: every hit the
run's scans returned so far (range noise included; each on its ray's canonical triangle,
``nbvdata.simulation.sensor``, so the same on every CPU), reduced to that many points by
farthest-point sampling (``nbvdata.core.cloud``); a noise-free view's hits are cached with its grid
update.

Random streams, all from the global seed and the mesh id (``SeedSequence`` spawn keys): 0 the
reference points, 1 the start views, 2 a run's range noise, 4 a run's moves and its policy
(3 is left to ``nbvtrain evaluate``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from nbvdata.core.cloud import ScannedCloud
from nbvdata.core.views import Pose
from nbvdata.simulation.grid import OccupancyGrid, ScanUpdate
from nbvdata.simulation.oracle import pack_bits
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.setcover import Cover, next_cover

if TYPE_CHECKING:
    from nbvdata.simulation.policy import Policy

# How a run leaves a state: the shards' ``move`` codes (``nbvdata.schema.shards.MOVE_RULES``);
# NO_MOVE: the run ended at that state.
ORACLE, EXPLORE, POLICY, NO_MOVE = 0, 1, 2, -1


class ViewCache:
    """Each candidate view's grid update and, with ``points``, its (H, 3) float32 hit points as
    the clouds keep them (``Scan.cloud_points``), computed on the first visit (noise-free scans
    only)."""

    def __init__(self, scene: Scene, points: bool = False):
        self.scene = scene
        self._updates: dict[int, ScanUpdate] = {}
        self._hits: dict[int, np.ndarray] | None = {} if points else None
        self._grid = scene.new_grid()  # scratch: only its marking buffers are used

    def update(self, view: int) -> ScanUpdate:
        if view not in self._updates:
            scan = self.scene.scanner.scan(self.scene.views[view], cloud=self._hits is not None)
            self._updates[view] = self._grid.scan_update(scan, self.scene.config.sensor.far)
            if self._hits is not None:
                self._hits[view] = scan.cloud_points
        return self._updates[view]

    def hit_points(self, view: int) -> np.ndarray:
        """(H, 3) float32 the view's hit points (a cache made with ``points``)."""
        self.update(view)
        return self._hits[view]


class Reconstruction:
    """The state of one simulated reconstruction: the occupancy grid and the covered points.

    grid : OccupancyGrid
    covered : (W,) uint64 packed mask of the covered reference points (see ``nbvdata.simulation.oracle``)
    cloud : every scan's hit points (``nbvdata.core.cloud.ScannedCloud``), or None when not kept
    """

    def __init__(self, scene: Scene, cache: ViewCache | None, rng: np.random.Generator, points: bool = False):
        """``cache`` None scans live (required when the sensor has range noise); ``points``:
        keep the scans' hit points (a cache must then have been made with ``points`` too)."""
        self.scene = scene
        self.cache = cache
        self.rng = rng
        self.grid: OccupancyGrid = scene.new_grid()
        self.covered = np.zeros(scene.oracle.visible.shape[1], dtype=np.uint64)
        self.scans = 0
        self.cloud: ScannedCloud | None = ScannedCloud() if points else None

    def scan(self, view: int) -> np.ndarray:
        """Scan from candidate ``view`` and integrate the scan; returns the (W,) packed reference
        points this scan covered (noise-free: the view's row of the oracle's bit matrix)."""
        if self.cache is None:
            return self.scan_pose(self.scene.views[view])
        self.grid.apply(self.cache.update(view))
        seen = self.scene.oracle.visible[view]
        self.covered |= seen
        self.scans += 1
        if self.cloud is not None:
            self.cloud.add(self.cache.hit_points(view))
        return seen

    def scan_pose(self, pose: Pose) -> np.ndarray:
        """Scan from any pose (a network's continuous prediction, say), cast live, and integrate;
        returns the (W,) packed reference points this scan covered.

        From a candidate view's pose with a noise-free sensor this gives the same grid and
        covered points as ``scan(view)``."""
        scan = self.scene.scanner.scan(pose, self.rng, cloud=self.cloud is not None)
        self.scene.integrate(self.grid, scan)
        seen = pack_bits(self.scene.coverage.covered_by(scan.hit_points))
        self.covered |= seen
        self.scans += 1
        if self.cloud is not None:
            self.cloud.add(scan.cloud_points)
        return seen


@dataclass
class LabelledRun:
    """The labelled states of one run, one list entry per state (see ``nbvdata.schema.shards``)."""

    log_odds: list[np.ndarray] = field(default_factory=list)
    nbv_index: list[int] = field(default_factory=list)
    gains: list[np.ndarray] = field(default_factory=list)
    overlaps: list[np.ndarray] = field(default_factory=list)
    coverage: list[tuple[float, float]] = field(default_factory=list)
    last_view: list[int] = field(default_factory=list)
    move: list[int] = field(default_factory=list)
    next_view: list[int] = field(default_factory=list)
    next_pose: list[np.ndarray] = field(default_factory=list)
    cover: list[np.ndarray] = field(default_factory=list)
    cover_size: list[int] = field(default_factory=list)
    cover_bound: list[int] = field(default_factory=list)
    cover_greedy: list[int] = field(default_factory=list)
    cover_seconds: list[float] = field(default_factory=list)  # not stored: timing, for reports
    points: list[np.ndarray] = field(default_factory=list)  # with state.points: (N, 3) float32 each
    points_count: list[int] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.nbv_index)

    def add_cover(self, cover: Cover, views: int, seconds: float) -> None:
        chosen = np.zeros(views, dtype=bool)
        chosen[list(cover.views)] = True
        self.cover.append(chosen)
        self.cover_size.append(cover.size)
        self.cover_bound.append(cover.bound)
        self.cover_greedy.append(cover.greedy)
        self.cover_seconds.append(seconds)


@dataclass
class Mover:
    """How a run leaves each state: by default to the labelled NBV (``ORACLE``). With
    ``explore`` > 0, with that probability to a uniformly random valid view (``EXPLORE``); with a
    ``policy``, otherwise to the policy's move (``POLICY``) but with probability ``oracle_mix`` to
    the NBV. ``rng`` draws one number per move (and the explored view): a run's own stream.
    """

    explore: float = 0.0
    policy: Policy | None = None
    oracle_mix: float = 0.0
    rng: np.random.Generator | None = None

    @classmethod
    def for_run(cls, explore: float, policy: Policy | None, oracle_mix: float, seed: int, mesh_id: str,
                run: int) -> "Mover":
        """Run ``run``'s mover, its streams spawned from the global seed, the mesh id and the run
        (spawn key 4), so neither the range noise nor the number of workers changes them."""
        moves, policy_stream = mesh_stream(seed, mesh_id, 4, run).spawn(2)
        if policy is not None:
            policy.start(policy_stream)
        return cls(explore, policy, oracle_mix, np.random.default_rng(moves))

    @property
    def follows_oracle(self) -> bool:
        """Whether every move is the NBV (no draws: the data of before exploration existed)."""
        return self.explore == 0 and self.policy is None

    def rule(self) -> int:
        """The rule of the next move: ORACLE, EXPLORE or POLICY."""
        if self.follows_oracle:
            return ORACLE
        draw = self.rng.random()
        if draw < self.explore:
            return EXPLORE
        if self.policy is not None and draw >= self.explore + (1 - self.explore) * self.oracle_mix:
            return POLICY
        return ORACLE


def mesh_stream(seed: int, mesh_id: str, *spawn_key: int) -> np.random.SeedSequence:
    """Stream ``spawn_key`` of a mesh (the keys are listed in the module docstring): entropy from
    the global seed and the mesh id's first 64 bits, never from a worker or a unit."""
    return np.random.SeedSequence([seed, int(mesh_id[:16], 16)], spawn_key=spawn_key)


def scene_rng(seed: int, mesh_id: str) -> np.random.Generator:
    """The generator that draws a mesh's coverage reference points."""
    return np.random.default_rng(mesh_stream(seed, mesh_id, 0))


def start_view(seed: int, mesh_id: str, view_count: int, run: int) -> int:
    """Start view of run ``run``: a seeded permutation of the views, so the first V runs differ."""
    order = np.random.default_rng(mesh_stream(seed, mesh_id, 1))
    return int(order.permutation(view_count)[run % view_count])


def run_seed(seed: int, mesh_id: str, run: int) -> int:
    """Seed of run ``run``'s own generator (range noise), from the global seed and the mesh id."""
    sequence = mesh_stream(seed, mesh_id, 2, run)
    return int(sequence.generate_state(1)[0])


def run_reconstruction(scene: Scene, start_view: int, rng: np.random.Generator,
                       cache: ViewCache | None, mover: Mover | None = None) -> LabelledRun:
    """One labelled run from ``start_view``; ``rng`` draws the range noise, if any; ``mover``
    chooses the moves (default: always the NBV). With ``oracle.cover`` every state also gets its
    set-cover label, each from the previous one (the first from the mesh's, ``Scene.empty_cover``)."""
    config = scene.config
    oracle = scene.oracle
    mover = mover if mover is not None else Mover()
    record = LabelledRun()
    clouds = config.state.points
    state = Reconstruction(scene, cache, rng, points=clouds > 0)
    state.scan(start_view)
    last, poses = start_view, [scene.views[start_view]]
    cover = scene.empty_cover() if config.oracle.cover else None
    exact = start_view if cache is not None else None  # the candidate whose exact points the scan added
    while True:
        scores = oracle.score(state.covered)
        nbv = scores.best(config.oracle.min_overlap, config.episode.min_gain)
        if nbv is None:
            break
        if cover is not None:
            started = time.perf_counter()
            cover = next_cover(oracle, state.covered, cover, exact, config.oracle.cover_node_limit)
            record.add_cover(cover, len(scene.views), time.perf_counter() - started)
        record.log_odds.append(state.grid.log_odds.copy())
        record.nbv_index.append(nbv)
        record.gains.append(scores.gains.astype(np.float32))
        record.overlaps.append(scores.overlaps.astype(np.float32))
        record.coverage.append((oracle.observable_coverage(state.covered),
                                oracle.observable_coverage(state.covered | oracle.visible[nbv])))
        record.last_view.append(last)
        if clouds:
            points, count = state.cloud.reduce(clouds)
            record.points.append(points)
            record.points_count.append(count)
        if state.scans >= config.episode.max_scans:
            record.move.append(NO_MOVE)
            record.next_view.append(-1)
            record.next_pose.append(np.full(6, np.nan))
            break
        rule = mover.rule()
        if rule == EXPLORE:
            valid = np.flatnonzero(scores.overlaps >= config.oracle.min_overlap)  # the NBV is one
            move: int | Pose = int(valid[mover.rng.integers(len(valid))])
        elif rule == POLICY:
            move = _policy_move(mover.policy, state.grid.probabilities(), tuple(poses), len(scene.views))
        else:
            move = nbv
        if isinstance(move, Pose):
            state.scan_pose(move)  # no candidate view: cast live
            last, pose, exact = -1, move, None
        else:
            state.scan(move)
            last, pose, exact = move, scene.views[move], move if cache is not None else None
        poses.append(pose)
        record.move.append(rule)
        record.next_view.append(last)
        record.next_pose.append(pose.xyzypr)
    return record


def _policy_move(policy: Policy, probabilities: np.ndarray, poses: tuple[Pose, ...], views: int) -> int | Pose:
    """The policy's move, checked: a candidate view's index in range, or a Pose."""
    move = policy.next_move(probabilities, poses)
    if isinstance(move, Pose):
        return move
    if isinstance(move, (int, np.integer)) and 0 <= move < views:
        return int(move)
    raise ValueError(f"policy {policy.name} moved to {move!r}: expected a Pose or a view index in 0..{views - 1}")
