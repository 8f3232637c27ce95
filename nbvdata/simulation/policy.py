"""The seam between the generator and a trained planner: ``nbvdata generate --policy CHECKPOINT``.

A run of a learned-policy rollout (one DAgger round) moves where a trained planner would, and
every state it reaches is still labelled by the exhaustive search (``nbvdata.simulation.episode``). nbvdata
never imports torch nor names a package that provides policies: it knows a policy only through
the small ``Policy`` protocol below, and finds the code that makes one from a file through the
entry-point group ``nbvdata.policies``. Each entry there names a *provider*: a callable
``(path: Path, config: SimConfig, threads: int) -> Policy`` (``threads`` > 0: use at most that
many threads). This project's ``nbvtrain`` registers ``checkpoint`` (its trained networks, the
default), in pyproject.toml::

    [project.entry-points."nbvdata.policies"]
    checkpoint = "nbvtrain.planners.provider:CheckpointPolicy"

and any installed package can register another (``--policy-provider NAME``). A provider is
imported by ``load_policy`` only when a policy is asked for. Workers get a ``PolicySource`` (a
path, the file's sha256 and the provider's name, plain data) and build the policy themselves,
once per process.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path
from typing import Protocol

import numpy as np

from nbvdata.core.config import ConfigError, SimConfig
from nbvdata.core.files import sha256_file
from nbvdata.core.views import Pose

USE_FIT = "pass a checkpoint written by nbvtrain fit (runs/NAME/best.pt)"
GROUP = "nbvdata.policies"
"""The entry-point group of policy providers."""
DEFAULT_PROVIDER = "checkpoint"
"""The provider of ``--policy`` without ``--policy-provider``: nbvtrain's trained networks."""
INSTALL_TRAIN = 'pip install torch==2.13.0 -e ".[train]"'


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
    """A file to follow: ``path``, its ``sha256``, the ``provider`` that makes a policy of it
    (a name in the ``nbvdata.policies`` group) and, once loaded, the policy's ``name``."""

    path: Path
    sha256: str
    name: str = field(default="", compare=False)
    provider: str = DEFAULT_PROVIDER

    @classmethod
    def from_path(cls, path: str | Path, provider: str = DEFAULT_PROVIDER) -> "PolicySource":
        path = Path(path)
        if not path.is_file():
            raise PolicyError(f"--policy {path}: no such checkpoint file; {USE_FIT}")
        return cls(path.resolve(), sha256_file(path), provider=provider)

    def record(self) -> dict:
        """What shards and the output folder record of it (no path: the same checkpoint anywhere
        gives the same bytes; the provider only when it is not the default, so that the default's
        records stay as they were)."""
        record = {"sha256": self.sha256, "network": self.name}
        return record if self.provider == DEFAULT_PROVIDER else record | {"provider": self.provider}


def check_policy(source: PolicySource, config: SimConfig) -> PolicySource:
    """Load the policy once (in the main process, before any work is given out): PolicyError or
    the checkpoint's own one-line error now rather than in every worker. Returns ``source`` with
    the policy's ``name``."""
    return PolicySource(source.path, source.sha256, load_policy(source, config).name, source.provider)


@functools.lru_cache(maxsize=2)
def load_policy(source: PolicySource, config: SimConfig, threads: int = 0) -> Policy:
    """The policy of ``source``, built by its provider (``provider``, imported here, and only
    here), once per process. ``config``: the run's settings (for nbvtrain's networks: the view
    sphere a regression network's direction is placed on, the candidate views a score network
    picks from; a checkpoint made in another scene is refused); ``threads`` > 0 limits the
    provider to that many threads (parallel workers pass 1)."""
    if sha256_file(source.path) != source.sha256:
        raise PolicyError(f"--policy {source.path}: the file changed while generating (sha256 "
                          f"{source.sha256[:12]}... expected): restore it, or start again")
    return load_provider(source.provider)(source.path, config, threads)


def load_provider(name: str):
    """The policy provider ``name`` of the ``nbvdata.policies`` entry-point group, imported;
    PolicyError naming the fix when no installed package registers it or it cannot be imported."""
    found = {point.value: point for point in entry_points(group=GROUP) if point.name == name}
    if len(found) != 1:
        if name == DEFAULT_PROVIDER and not found:  # nbvtrain's entry point: the project is not installed
            raise PolicyError(f"--policy needs nbvtrain and PyTorch: no installed package registers the {name!r} "
                              f"policy provider (entry-point group {GROUP}): {INSTALL_TRAIN} (again after updating "
                              "a checkout: entry points are read from what pip installed)")
        known = sorted({point.name for point in entry_points(group=GROUP)})
        problem = (f"several packages register the policy provider {name!r} ({', '.join(sorted(found))})" if found
                   else f"no installed package registers the policy provider {name!r}")
        raise PolicyError(f"--policy-provider {name}: {problem}; installed providers: {', '.join(known) or 'none'} "
                          f"(entry-point group {GROUP})")
    (point,) = found.values()
    try:
        return point.load()
    except ImportError as error:
        if name == DEFAULT_PROVIDER:
            raise PolicyError(f"--policy needs nbvtrain and PyTorch, which cannot be imported ({error}): "
                              f"{INSTALL_TRAIN}") from None
        raise PolicyError(f"--policy-provider {name}: {point.value} cannot be imported ({error}): install what it "
                          "needs") from None
