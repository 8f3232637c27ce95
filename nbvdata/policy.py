"""The seam between the generator and a trained planner: ``nbvdata generate --policy CHECKPOINT``.

A run of a learned-policy rollout (one DAgger round) moves where a trained planner would, and
every state it reaches is still labelled by the exhaustive search (``nbvdata.episode``). nbvdata
never imports torch: it knows a policy only through the small ``Policy`` protocol below. The
torch implementation lives in ``nbvtrain.policy`` and is imported by ``load_policy`` only when
a policy is asked for. Workers get a ``PolicySource`` (a path and the file's sha256, plain data)
and build the policy themselves, once per process.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from nbvdata.config import ConfigError, SimConfig
from nbvdata.mesh import sha256_file
from nbvdata.views import Pose

USE_FIT = "pass a checkpoint written by nbvtrain fit (runs/NAME/best.pt)"


class PolicyError(ConfigError):
    """A policy that cannot be used; the one-line message names the fix."""


class Policy(Protocol):
    """A planner the runs follow. ``name`` says what it is (e.g. "nbvnet-4-5 epoch 12").

    One instance serves every run of a process, and every thread of the threading backend: a
    policy keeps no state between calls but what ``start`` sets (``CheckpointPolicy`` keeps none).
    """

    name: str

    def start(self, seed: np.random.SeedSequence) -> None:
        """Called before every run with that run's own stream for the policy."""

    def next_move(self, probabilities: np.ndarray, poses: tuple[Pose, ...]) -> int | Pose:
        """The next scan at a state: a candidate view's index, or any sensor pose.

        probabilities : (n, n, n) float32 occupancy grid, authors' encoding (0.5 = unknown)
        poses : the poses scanned so far, oldest first
        """


@dataclass(frozen=True)
class PolicySource:
    """A checkpoint to follow: ``path``, its file's ``sha256`` and, once loaded, ``name``."""

    path: Path
    sha256: str
    name: str = field(default="", compare=False)

    @classmethod
    def from_path(cls, path: str | Path) -> "PolicySource":
        path = Path(path)
        if not path.is_file():
            raise PolicyError(f"--policy {path}: no such checkpoint file; {USE_FIT}")
        return cls(path.resolve(), sha256_file(path))

    def record(self) -> dict:
        """What shards and the output folder record of it (no path: the same checkpoint anywhere
        gives the same bytes)."""
        return {"sha256": self.sha256, "network": self.name}


def check_policy(source: PolicySource, config: SimConfig) -> PolicySource:
    """Load the policy once (in the main process, before any work is given out): PolicyError or
    the checkpoint's own one-line error now rather than in every worker. Returns ``source`` with
    the policy's ``name``."""
    return PolicySource(source.path, source.sha256, load_policy(source, config).name)


@functools.lru_cache(maxsize=2)
def load_policy(source: PolicySource, config: SimConfig, threads: int = 0) -> Policy:
    """The policy of ``source``, built by ``nbvtrain.policy`` (imported here, and only here), once
    per process. ``config``: the run's settings (the view sphere a regression network's direction
    is placed on, the candidate views a score network picks from; a checkpoint made in another
    scene is refused); ``threads`` > 0 limits torch to that many threads (parallel workers pass 1)."""
    if sha256_file(source.path) != source.sha256:
        raise PolicyError(f"--policy {source.path}: the file changed while generating (sha256 "
                          f"{source.sha256[:12]}... expected): restore it, or start again")
    try:
        from nbvtrain.policy import CheckpointPolicy
    except ImportError as error:
        raise PolicyError(f"--policy needs nbvtrain and PyTorch, which cannot be imported ({error}): "
                          'pip install torch==2.13.0 -e ".[train]"') from None
    return CheckpointPolicy(source.path, config, threads)
