"""How good predicted NBV positions are: the paper's MSE and MAE, the angular error, and, where
the shards carry every candidate's gain and overlap, the gain ratio and the invalid share.

All functions take predictions and targets as (N, 3) arrays of positions on the unit sphere
(targets exactly unit, predictions as the network gives them).

The gain ratio judges a prediction the way the label was made (``nbvdata.simulation.oracle``): the
prediction picks the candidate view nearest to it; a valid pick (overlap >= the data's
``oracle.min_overlap``) scores its gain over the best valid gain (the label's), an invalid
one scores 0. The exact labels score exactly 1; the invalid share says how often the picks
broke the overlap rule.
"""

from __future__ import annotations

import numpy as np

METRICS = ("mse", "mae", "angle_deg", "gain_ratio", "invalid_share")


def unit(vectors: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3) scaled to length 1 (zero rows stay zero)."""
    norm = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return np.divide(vectors, norm, out=np.zeros_like(vectors, dtype=np.float64), where=norm > 0)


def angle_deg(predictions: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(N,) angle in degrees between each prediction's direction and its target's."""
    cosine = np.einsum("ij,ij->i", unit(predictions), unit(targets))
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def nearest_view(predictions: np.ndarray, view_units: np.ndarray) -> np.ndarray:
    """(N,) index of the candidate view (view_units (V, 3)) nearest in direction to each prediction."""
    return np.argmax(unit(predictions) @ view_units.T, axis=1)


def gain_ratio(predictions: np.ndarray, gains: np.ndarray, valid: np.ndarray,
               view_units: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((M,) gain ratio, (M,) bool invalid pick) of the M states whose best valid view gains
    something: the gain of the candidate nearest to each prediction over the best valid gain,
    0 when that candidate breaks the overlap rule.

    gains (N, V), valid (N, V) bool (overlap >= min_overlap), view_units (V, 3).
    """
    gains, valid = np.asarray(gains, dtype=np.float64), np.asarray(valid, dtype=bool)
    if gains.shape != valid.shape:
        raise ValueError(f"gains {gains.shape} and valid {valid.shape} must have the same shape (N, V)")
    rows = np.arange(len(gains))
    nearest = nearest_view(predictions, view_units)
    best = np.where(valid, gains, 0.0).max(axis=1, initial=0.0)
    picked_valid = valid[rows, nearest]
    chosen = np.where(picked_valid, gains[rows, nearest], 0.0)
    keep = best > 0
    return chosen[keep] / best[keep], ~picked_valid[keep]


def evaluate(predictions: np.ndarray, targets: np.ndarray, gains: np.ndarray | None = None,
             view_units: np.ndarray | None = None, valid: np.ndarray | None = None) -> dict[str, float]:
    """{mse, mae, angle_deg, gain_ratio, invalid_share} means; the last two are NaN without
    gains, view_units and valid ((N, V) bool, see ``gain_ratio``).

    mse and mae average over all N x 3 components, as the paper's (and torch's) losses do.
    """
    predictions = np.asarray(predictions, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64)
    error = predictions - targets
    ratio = invalid = float("nan")
    if gains is not None and view_units is not None and valid is not None:
        ratios, invalids = gain_ratio(predictions, gains, valid, view_units)
        if len(ratios):
            ratio, invalid = float(ratios.mean()), float(invalids.mean())
    return {"mse": float(np.mean(error ** 2)), "mae": float(np.mean(np.abs(error))),
            "angle_deg": float(angle_deg(predictions, targets).mean()), "gain_ratio": ratio,
            "invalid_share": invalid}


def format_ratio(value: float) -> str:
    """A gain ratio (or share) for printing, or "-" for shards without score vectors (imported ones)."""
    return "-" if np.isnan(value) else f"{value:.3f}"
