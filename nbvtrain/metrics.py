"""How good predicted NBV positions are: the paper's MSE and MAE, the angular error, and, where
the shards carry every candidate's gain, the gain ratio.

All functions take predictions and targets as (N, 3) arrays of positions on the unit sphere
(targets exactly unit, predictions as the network gives them).
"""

from __future__ import annotations

import numpy as np

METRICS = ("mse", "mae", "angle_deg", "gain_ratio")


def unit(vectors: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3) scaled to length 1 (zero rows stay zero)."""
    norm = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return np.divide(vectors, norm, out=np.zeros_like(vectors, dtype=np.float64), where=norm > 0)


def angle_deg(predictions: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(N,) angle in degrees between each prediction's direction and its target's."""
    cosine = np.einsum("ij,ij->i", unit(predictions), unit(targets))
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def gain_ratio(predictions: np.ndarray, gains: np.ndarray, view_units: np.ndarray) -> np.ndarray:
    """(N,) ground-truth gain of the candidate view nearest to each prediction / the best gain.

    gains (N, V), view_units (V, 3). States where no view gains anything are left out.
    """
    nearest = np.argmax(unit(predictions) @ view_units.T, axis=1)
    best = gains.max(axis=1)
    chosen = gains[np.arange(len(gains)), nearest]
    keep = best > 0
    return chosen[keep] / best[keep]


def evaluate(predictions: np.ndarray, targets: np.ndarray, gains: np.ndarray | None = None,
             view_units: np.ndarray | None = None) -> dict[str, float]:
    """{mse, mae, angle_deg, gain_ratio} means; gain_ratio is NaN without gains.

    mse and mae average over all N x 3 components, as the paper's (and torch's) losses do.
    """
    predictions = np.asarray(predictions, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64)
    error = predictions - targets
    ratio = float("nan")
    if gains is not None and view_units is not None:
        ratios = gain_ratio(predictions, gains, view_units)
        ratio = float(ratios.mean()) if len(ratios) else float("nan")
    return {"mse": float(np.mean(error ** 2)), "mae": float(np.mean(np.abs(error))),
            "angle_deg": float(angle_deg(predictions, targets).mean()), "gain_ratio": ratio}


def format_ratio(value: float) -> str:
    """A gain ratio for printing, or "-" for shards without score vectors (imported ones)."""
    return "-" if np.isnan(value) else f"{value:.3f}"
