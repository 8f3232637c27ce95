"""The planners' common ground: what a planner decides from (``Observation``), the interface
(``Planner.next_pose(observation, truth) -> Pose``) and the registry: ``PLANNERS`` maps each
name ``--planners`` takes to a ``PlannerKind`` (what it reads, its options, what it chooses, how it
is built from a ``PlannerContext``); each family's module joins it with ``@register_planner``,
and ``build_planners``, the CLI's check, the docs' table (``planner_table``) and the tests are
made from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from nbvdata.core.config import SimConfig
from nbvdata.core.views import Pose, ViewSet
from nbvdata.simulation.episode import Reconstruction

READS = {"grid": "the grid", "poses": "the poses scanned", "points": "the points scanned",
         "seed": "a seeded generator", "scene": "the simulation (privileged: an upper bound, not a method)"}
"""What a planner may decide from (``PlannerKind.reads``), in the docs' words."""


def robot_radius(config: SimConfig) -> float:
    """The object's bounding sphere as a robot knows it (metres): ``mesh.object_size`` sqrt(3) / 2, the
    half-diagonal of the cube its largest side spans; the sphere a path round the object avoids."""
    return config.mesh.object_size * math.sqrt(3) / 2


@dataclass(frozen=True)
class Observation:
    """What a robot knows at a state.

    probabilities : (n, n, n) float32 occupancy grid, authors' encoding (0.5 = unknown)
    poses : the sensor poses scanned so far, oldest first
    points : (M, 3) float32 every point scanned so far, object frame, oldest scan first
             (``nbvdata.core.cloud.ScannedCloud``); None when the run keeps none
    """

    probabilities: np.ndarray
    poses: tuple[Pose, ...]
    points: np.ndarray | None = None

    @property
    def positions(self) -> np.ndarray:
        """(P, 3) float64 the sensor positions of ``poses``, object frame."""
        return np.array([pose.position for pose in self.poses], dtype=np.float64).reshape(-1, 3)


class Planner:
    """Base class. ``privileged`` planners also receive the simulation's state (the oracle);
    ``reads_points`` ones the scanned points (``Observation.points``)."""

    name = "planner"
    privileged = False
    reads_points = False

    def start(self, seed: int | np.random.SeedSequence) -> None:
        """Called before every reconstruction; ``seed`` is that reconstruction's stream for the
        planner (spawned apart from the sensor noise's)."""

    def next_pose(self, observation: Observation, truth: Reconstruction | None = None) -> Pose:
        raise NotImplementedError


@dataclass(frozen=True)
class PlannerKind:
    """A registered planner. ``name``: what ``--planners`` names; ``reads``: what it decides from
    (keys of ``READS``; "scene" only for a privileged planner); ``options``: the flags that change
    it; ``chooses``: what it picks, for the docs' table; ``default``: in ``nbvtrain evaluate``'s
    default list; ``build``: ``PlannerContext`` -> its planners (one, or one per option value)."""

    name: str
    reads: tuple[str, ...]
    options: tuple[str, ...]
    chooses: str
    default: bool
    build: Callable[["PlannerContext"], list[Planner]]


PLANNERS: dict[str, PlannerKind] = {}
"""Every registered planner, by name, in the order they registered (the docs' and the CLI's)."""


def register_planner(name: str, reads: Sequence[str], chooses: str, options: Sequence[str] = (),
                     default: bool = True) -> Callable:
    """Decorator: register ``build(context) -> list[Planner]`` as the planner ``name``."""
    unknown = set(reads) - set(READS)
    if unknown:
        raise ValueError(f"planner {name}: reads {sorted(unknown)}, not among {sorted(READS)}")

    def register(build: Callable[["PlannerContext"], list[Planner]]) -> Callable:
        PLANNERS[name] = PlannerKind(name, tuple(reads), tuple(options), chooses, default, build)
        return build
    return register


def default_planners() -> list[str]:
    """The names ``nbvtrain evaluate`` runs when ``--planners`` is not given."""
    return [name for name, kind in PLANNERS.items() if kind.default]


class Skipped(Exception):
    """A planner that cannot be built here: the message says why (no checkpoint for its task: and
    what to pass). ``views``: where the planner plays one view set only, its (layout, count), from
    which each command says its own fix (``fix``)."""

    def __init__(self, message: str, views: tuple[str, int] | None = None):
        super().__init__(message)
        self.views = views

    def fix(self, settings: str) -> str:
        """The message, ending in ``settings`` (the command's way to run on ``views``) where there are views."""
        return f"{self}: {settings}" if self.views is not None else str(self)


@dataclass(frozen=True)
class PlannerContext:
    """What the planners are built from: the simulation settings, the run's candidate views, the
    checkpoints by task (None: the released model) and the evaluation's options."""

    config: SimConfig
    views: ViewSet
    checkpoints: dict[str, Path | Sequence[Path] | None]
    no_stall: bool = False
    tta: bool = False
    hybrid_weights: Sequence[float] = (1.0,)
    hybrid_stride: int = 4
    spread: float | None = None
    foreign_views: bool = False

    def checkpoint(self, task: str) -> Path | Sequence[Path]:
        """The checkpoint(s) of ``task``: given, else the released one; ``Skipped`` when neither."""
        from nbvtrain.planners.released import NoReleasedModel, released_checkpoint

        path = self.checkpoints.get(task)
        if path is not None:
            return path
        try:
            return released_checkpoint(task)
        except NoReleasedModel as reason:
            raise Skipped(str(reason)) from None


def planner_table() -> list[str]:
    """The docs' table of the registered planners (docs/evaluation.md holds it verbatim)."""
    lines = ["| planner | decides from | chooses | options |", "|---|---|---|---|"]
    for kind in PLANNERS.values():
        reads = " and ".join(READS[key] for key in kind.reads)
        extra = "" if kind.default else " (not in the default list)"
        lines.append(f"| `{kind.name}` | {reads} | {kind.chooses}{extra} | {'; '.join(kind.options) or '-'} |")
    lines.append("| `module:function` | the grid and the poses scanned (the environment's observation) | a policy's "
                 "candidate view or direction (`PolicyPlanner`, e.g. trained by RL) | - |")
    return lines
