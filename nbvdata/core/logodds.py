"""OctoMap's log-odds and the occupancy probabilities they stand for: the arithmetic the grid
(``nbvdata.simulation.grid``) updates with and the shard schema (``nbvdata.schema.shards``) decodes with, kept apart
from both so that reading a shard loads no simulator.
"""

from __future__ import annotations

import math

import numpy as np


def logodds(probability: float) -> np.float32:
    """OctoMap's ``logodds``: computed in double, stored as float."""
    return np.float32(math.log(probability / (1.0 - probability)))


def probability(log_odds: np.ndarray) -> np.ndarray:
    """float32 occupancy probability of float32 log-odds (computed in float64); 0 -> exactly 0.5."""
    return (1.0 - 1.0 / (1.0 + np.exp(np.asarray(log_odds, dtype=np.float64)))).astype(np.float32)
