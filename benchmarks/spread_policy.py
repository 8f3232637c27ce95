"""Policies that spread the views away from those already scanned, for ``nbvtrain evaluate
--planners benchmarks/spread_policy.py:NAME`` (issue 27: can the view state lift the regression
network above a random view?).

- ``farthest``: no network - the unscanned candidate view farthest (in angle) from every
  scanned one; the baseline the others must beat to show the network adds anything.
- ``regression_w0``, ``regression_w05``, ``regression_w1``, ``regression_w2``: the released
  regression network's answer d, then the unscanned candidate view v with the highest
  cos(d, v) - W * max over scanned s of cos(v, s) (W = 0: the unscanned view nearest the answer).

Candidate views are the default scene's (500 on the upper hemisphere); the observation's
``taken`` (V,) marks the scanned ones.
"""

from __future__ import annotations

import functools

import numpy as np

from nbvdata.config import ViewConfig
from nbvdata.views import view_sphere


@functools.cache
def _units() -> np.ndarray:
    """(V, 3) unit directions of the default scene's candidate views."""
    return view_sphere(ViewConfig()).unit_positions


@functools.cache
def _predictor():
    from nbvtrain.predict import Predictor
    from nbvtrain.release import released_checkpoint

    return Predictor(released_checkpoint("regression"))


def _closeness(taken: np.ndarray) -> np.ndarray:
    """(V,) the cosine from each candidate view to its nearest scanned view (-1 with none)."""
    units = _units()
    scanned = units[np.asarray(taken, dtype=bool)]
    if not len(scanned):
        return np.full(len(units), -1.0)
    return (units @ scanned.T).max(axis=1)


def _pick(score: np.ndarray, taken: np.ndarray) -> int:
    score = np.where(np.asarray(taken, dtype=bool), -np.inf, score)
    return int(np.argmax(score))


def farthest(observation: dict) -> int:
    return _pick(-_closeness(observation["taken"]), observation["taken"])


def _regression(observation: dict, weight: float) -> int:
    (prediction,) = _predictor().predict(observation["grid"])
    direction = np.asarray(prediction.direction, dtype=np.float64)
    score = _units() @ direction - weight * _closeness(observation["taken"])
    return _pick(score, observation["taken"])


regression_w0, regression_w05, regression_w1, regression_w2 = (functools.partial(_regression, weight=w)
                                                              for w in (0.0, 0.5, 1.0, 2.0))


@functools.cache
def _score_predictor():
    from nbvtrain.predict import Predictor
    from nbvtrain.release import released_checkpoint

    return Predictor(released_checkpoint("scores"))


def _scores(observation: dict, weight: float) -> int:
    """The released score network's standardised scores plus ``weight`` times the standardised
    angular distance to the nearest scanned view, both over the unscanned views."""
    from nbvtrain.scores import standardise

    taken = np.asarray(observation["taken"], dtype=bool)
    free = ~taken
    scores = _score_predictor().raw(observation["grid"], taken)[0]
    score = standardise(scores, free) + weight * standardise(-_closeness(taken), free)
    return _pick(score, taken)


scores_s0, scores_s025, scores_s05, scores_s1 = (functools.partial(_scores, weight=w) for w in (0.0, 0.25, 0.5, 1.0))
