"""Tiny policies on ``nbvdata.env``'s observation, for ``nbvtrain evaluate --planners
env_policies:NAME`` in tests/test_env.py."""

import numpy as np

SEEN: list[dict] = []  # every observation ``first_untaken`` was given, in order


def first_untaken(observation: dict) -> int:
    """The candidate view of lowest index not scanned yet."""
    SEEN.append(observation)
    return int(np.argmin(observation["taken"]))


def toward_unknown(observation: dict) -> np.ndarray:
    """A direction: from the grid's centre towards the mean of its unknown voxels, tilted up."""
    grid = observation["grid"]
    unknown = np.argwhere(grid == 0.5) - (grid.shape[0] - 1) / 2
    return unknown.mean(axis=0) / grid.shape[0] + np.array([0.0, 0.0, 0.5])


def bad(observation: dict) -> str:
    return "left"


def crashes(observation: dict) -> int:
    """A policy with a bug: it raises on every decision."""
    return _deeper(observation)


def _deeper(observation: dict) -> int:
    raise ZeroDivisionError("a bug in the user's policy")
