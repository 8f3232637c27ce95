"""Reference predictors for the README's table, scored on the same split as the networks.

- mean direction: every validation state gets the mean training target, scaled to unit length
  (a valid view);
- mean vector: the mean training target as it is, inside the sphere: the constant with the
  lowest MSE, what a network that has learnt nothing of the grid converges to;
- nearest neighbour: each validation grid gets the label of the training grid closest to it
  (Euclidean distance between the occupancy-probability grids);
- farthest view: the unscanned candidate view farthest in angle from every view the state's run
  scanned (its view state; ``nbvdata.core.views.farthest_view``), learning nothing: what spreading the
  views alone scores. It needs the view states of ``nbvdata generate``'s shards (``Skipped``
  for imported data).
"""

from __future__ import annotations

import numpy as np
import torch

from nbvdata.core.views import farthest_view
from nbvdata.schema.shards import ShardError
from nbvtrain.networks.metrics import evaluate, unit
from nbvtrain.networks.training_data import ShardSet, load_view_states, to_grids


class Skipped(Exception):
    """A baseline the data cannot give; its message says why."""


def mean_direction(data: ShardSet, train_idx: np.ndarray, val_idx: np.ndarray) -> dict[str, float]:
    mean = unit(data.targets[train_idx].mean(axis=0, keepdims=True))
    predictions = np.repeat(mean, len(val_idx), axis=0)
    return _score(data, predictions, val_idx)


def mean_vector(data: ShardSet, train_idx: np.ndarray, val_idx: np.ndarray) -> dict[str, float]:
    mean = data.targets[train_idx].mean(axis=0, keepdims=True)
    return _score(data, np.repeat(mean, len(val_idx), axis=0), val_idx)


def nearest_neighbour_indices(data: ShardSet, train_idx: np.ndarray, val_idx: np.ndarray,
                              block: int = 1024) -> np.ndarray:
    """(len(val_idx),) the training sample whose grid is nearest to each validation grid.

    ||a - b||^2 = |a|^2 + |b|^2 - 2 a.b over flattened float32 grids, in blocks, by matrix
    products (float64 accumulation would change nothing here: ties are broken by the lower index).
    """
    palette = torch.from_numpy(data.palette)
    train_norms = torch.empty(len(train_idx))
    train_blocks = []
    for i in range(0, len(train_idx), block):
        grids = to_grids(data.grids.take(train_idx[i:i + block]), palette).flatten(1)
        train_norms[i:i + len(grids)] = (grids * grids).sum(dim=1)
        train_blocks.append(grids)
    best = np.empty(len(val_idx), dtype=np.int64)
    for j in range(0, len(val_idx), block):
        queries = to_grids(data.grids.take(val_idx[j:j + block]), palette).flatten(1)
        distances = torch.cat([train_norms[i * block:i * block + len(b)][None] - 2 * queries @ b.T
                               for i, b in enumerate(train_blocks)], dim=1)
        best[j:j + len(queries)] = distances.argmin(dim=1).numpy()
    return train_idx[best]


def nearest_neighbour(data: ShardSet, train_idx: np.ndarray, val_idx: np.ndarray) -> dict[str, float]:
    neighbours = nearest_neighbour_indices(data, train_idx, val_idx)
    return _score(data, data.targets[neighbours], val_idx)


def farthest(data: ShardSet, train_idx: np.ndarray, val_idx: np.ndarray) -> dict[str, float]:
    if data.view_units is None:
        raise Skipped("the shards hold no candidate views (imported data)")
    try:
        taken = load_view_states(data.paths, poses="nearest")[val_idx]
    except ShardError as error:
        raise Skipped(str(error)) from None
    units = data.view_units
    predictions = np.array([units[farthest_view(units, units[scanned])] for scanned in taken]).reshape(-1, 3)
    return _score(data, predictions, val_idx)


def _score(data: ShardSet, predictions: np.ndarray, val_idx: np.ndarray) -> dict[str, float]:
    gains = data.gains[val_idx] if data.gains is not None else None
    valid = data.valid[val_idx] if data.valid is not None else None
    return evaluate(predictions, data.targets[val_idx], gains, data.view_units, valid)


BASELINES = {"mean direction": mean_direction, "mean vector": mean_vector, "nearest neighbour": nearest_neighbour,
             "farthest view": farthest}
