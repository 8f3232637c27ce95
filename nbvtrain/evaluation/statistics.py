"""Statistics that can decide between planners: per-object paired differences against a
reference planner, percentile bootstrap confidence intervals over objects, win / tie / loss
counts, and a ranking that says "not separable" where an interval holds 0.

The unit is the object: a planner's value on an object is the mean over its start views, so a
difference between two planners is paired on the same object and starts, and the bootstrap
resamples objects (with replacement, ``RESAMPLES`` times, from a seeded generator: the same
interval for the same values and seed). A 95 % interval is the 2.5th to 97.5th percentile of the
resampled means.

Below ``MIN_OBJECTS`` objects no interval decides: ``Comparison.decided`` is False and
``ranking`` gives the interval without "ahead of" or "not separable from".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nbvdata.core.text import plural

RESAMPLES = 10_000
LEVEL = 0.95
MIN_OBJECTS = 20
"""The fewest objects whose intervals decide. A percentile bootstrap interval of a mean is too
narrow on few values (it uses the normal quantile and the spread of the values as they are,
where Student's t and the n - 1 spread apply): for per-object values drawn from a normal
distribution a 95 % interval holds the true mean about 93 % of the time on 20 objects, 90 % on
10, 82 % on 5 and 51 % on 2 (1,000 simulated draws each; exponential, skewed, values do worse:
88, 86, 80 and 49 %). From 20 objects on it is within a few points of its nominal level
(``tests/test_statistics.py`` measures it)."""


def bootstrap_interval(values: np.ndarray, seed: int, resamples: int = RESAMPLES,
                       level: float = LEVEL) -> tuple[float, float]:
    """(low, high): the percentile bootstrap interval of the mean of ``values`` (N,) over
    ``resamples`` resamplings with replacement; (nan, nan) for no values."""
    values = np.asarray(values, dtype=np.float64)
    if not len(values):
        return float("nan"), float("nan")
    picks = np.random.default_rng(seed).integers(0, len(values), size=(resamples, len(values)))
    means = values[picks].mean(axis=1)
    tail = (1.0 - level) / 2.0
    low, high = np.quantile(means, [tail, 1.0 - tail])
    return float(low), float(high)


@dataclass(frozen=True)
class Comparison:
    """A planner against the reference, over the objects both have: ``mean`` of the per-object
    differences (planner - reference), its interval, and how many objects the planner won, tied
    (|difference| <= ``tie``) and lost."""

    planner: str
    reference: str
    objects: int
    mean: float
    low: float
    high: float
    wins: int
    ties: int
    losses: int

    @property
    def separable(self) -> bool:
        """Whether the interval excludes 0 (on any number of objects: ``decided`` says whether
        that is evidence)."""
        return not self.low <= 0.0 <= self.high

    @property
    def decided(self) -> bool:
        """Whether the comparison has the ``MIN_OBJECTS`` objects an interval needs to decide."""
        return self.objects >= MIN_OBJECTS

    @property
    def verdict(self) -> str:
        """What a table says of it: "yes" (separable), "no", or "no verdict" below ``MIN_OBJECTS``."""
        if not self.decided:
            return "no verdict"
        return "yes" if self.separable else "no"


def compare(values: dict[str, np.ndarray], reference: str, seed: int, tie: float = 1e-9,
            higher_is_better: bool = True) -> list[Comparison]:
    """Each planner of ``values`` (planner -> (O,) per-object values, NaN where it has none)
    against ``reference``, on the objects where both have a value. ``higher_is_better`` False
    (a path length, a Chamfer distance): a win is a lower value. The interval of each planner is
    drawn from its own stream (``seed`` and its position), so adding a planner changes no other's."""
    base = np.asarray(values[reference], dtype=np.float64)
    comparisons = []
    for index, (planner, own) in enumerate(values.items()):
        own = np.asarray(own, dtype=np.float64)
        common = np.isfinite(own) & np.isfinite(base)
        difference = own[common] - base[common]
        better = difference if higher_is_better else -difference
        low, high = bootstrap_interval(difference, seed + index)
        comparisons.append(Comparison(planner, reference, int(common.sum()),
                                      float(difference.mean()) if len(difference) else float("nan"), low, high,
                                      int((better > tie).sum()), int((np.abs(better) <= tie).sum()),
                                      int((better < -tie).sum())))
    return comparisons


def ranking(values: dict[str, np.ndarray], seed: int, higher_is_better: bool = True) -> list[tuple[str, float, str]]:
    """Planners by mean over the objects all of them have (best first), each with its mean and
    what separates it from the next one down: "ahead of NEXT (interval LOW..HIGH)" when the
    paired interval of (it - next) excludes 0, "not separable from NEXT (...)" when it holds 0;
    on fewer than ``MIN_OBJECTS`` objects no verdict: "LOW..HIGH against NEXT (no verdict on
    N objects)"."""
    stacked = np.array([np.asarray(v, dtype=np.float64) for v in values.values()])
    common = np.isfinite(stacked).all(axis=0)
    means = {planner: float(np.asarray(v, dtype=np.float64)[common].mean()) for planner, v in values.items()}
    order = sorted(means, key=lambda planner: (-means[planner] if higher_is_better else means[planner], planner))
    rows = []
    for position, planner in enumerate(order):
        if position + 1 == len(order):
            rows.append((planner, means[planner], ""))
            continue
        after = order[position + 1]
        difference = np.asarray(values[planner], dtype=np.float64)[common] - np.asarray(values[after],
                                                                                         dtype=np.float64)[common]
        low, high = bootstrap_interval(difference, seed + position)
        if common.sum() < MIN_OBJECTS:
            rows.append((planner, means[planner], f"{low:+.2f}..{high:+.2f} against {after} (no verdict on "
                                                  f"{plural(int(common.sum()), 'object')})"))
            continue
        verdict = "not separable from" if low <= 0.0 <= high else "ahead of"
        rows.append((planner, means[planner], f"{verdict} {after} ({low:+.2f}..{high:+.2f})"))
    return rows


def tertiles(values: np.ndarray) -> np.ndarray:
    """(O,) int 0, 1, 2: which third of ``values`` (O,) each object falls in, lowest first (ties
    by object order: the first third of the objects sorted by value)."""
    values = np.asarray(values, dtype=np.float64)
    order = np.argsort(values, kind="stable")
    thirds = np.empty(len(values), dtype=np.int64)
    thirds[order] = np.minimum((np.arange(len(values)) * 3) // max(len(values), 1), 2)
    return thirds
