"""Policies that spread the views away from those already scanned, for ``nbvtrain evaluate
--planners recipes/spread_policy.py:NAME`` (issue 27: can the view state lift the regression
network above a random view?).

- ``farthest``: no network - the unscanned candidate view farthest (in angle) from every
  scanned one; the baseline the others must beat to show the network adds anything.
- ``regression_w0``, ``regression_w05``, ``regression_w1``, ``regression_w2``: the released
  regression network's answer d, then the unscanned candidate view v with the highest
  cos(d, v) - W * max over scanned s of cos(v, s) (W = 0: the unscanned view nearest the answer).
- ``scores_s0``, ``scores_s025``, ``scores_s05``, ``scores_s1``: the released score network's
  standardised scores plus W times the standardised angular distance to the nearest scan.

The first two are the built-in ``farthest`` planner and ``nbvtrain evaluate --spread W`` as
policies (``nbvdata.core.views``; they give the same runs); candidate views are the default scene's
(500 on the upper hemisphere), the observation's ``taken`` (V,) marks the scanned ones.
"""

from __future__ import annotations

import functools

import numpy as np

from nbvdata.core.config import ViewConfig
from nbvdata.core.views import farthest_view, nearest_scan_cosines, spread_view, view_sphere


@functools.cache
def _units() -> np.ndarray:
    """(V, 3) unit directions of the default scene's candidate views."""
    return view_sphere(ViewConfig()).unit_positions


@functools.cache
def _predictor():
    from nbvtrain.networks.predict import Predictor
    from nbvtrain.planners.released import released_checkpoint

    return Predictor(released_checkpoint("regression"))


def _scanned(observation: dict) -> np.ndarray:
    """(P, 3) unit directions of the scanned candidate views."""
    return _units()[np.asarray(observation["taken"], dtype=bool)]


def farthest(observation: dict) -> int:
    return farthest_view(_units(), _scanned(observation))


def _regression(observation: dict, weight: float) -> int:
    (prediction,) = _predictor().predict(observation["grid"])
    return spread_view(_units(), _scanned(observation), prediction.direction, weight)


regression_w0, regression_w05, regression_w1, regression_w2 = (functools.partial(_regression, weight=w)
                                                              for w in (0.0, 0.5, 1.0, 2.0))


@functools.cache
def _score_predictor():
    from nbvtrain.networks.predict import Predictor
    from nbvtrain.planners.released import released_checkpoint

    return Predictor(released_checkpoint("scores"))


def _scores(observation: dict, weight: float) -> int:
    """The released score network's standardised scores plus ``weight`` times the standardised
    angular distance to the nearest scanned view, both over the unscanned views."""
    from nbvtrain.networks.scores import standardise

    taken = np.asarray(observation["taken"], dtype=bool)
    free = ~taken
    scores = _score_predictor().raw(observation["grid"], taken)[0]
    score = standardise(scores, free) + weight * standardise(-nearest_scan_cosines(_units(), _scanned(observation)), free)
    return int(np.argmax(np.where(taken, -np.inf, score)))


scores_s0, scores_s025, scores_s05, scores_s1 = (functools.partial(_scores, weight=w) for w in (0.0, 0.25, 0.5, 1.0))
