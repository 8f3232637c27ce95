"""``build_planners``: the named planners of a run - registered ones (``PLANNERS``, every family
imported by the package) and ``module:function`` policies - and what was skipped, and why."""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Sequence

from nbvdata.core.config import ConfigError, SimConfig
from nbvdata.core.views import ViewSet
from nbvtrain.planners.base import PLANNERS, Planner, PlannerContext, Skipped
from nbvtrain.planners.policies import PolicyPlanner


def build_planners(names: list[str], config: SimConfig, views: ViewSet,
                   checkpoints: dict[str, Path | Sequence[Path] | None], no_stall: bool = False, tta: bool = False,
                   hybrid_weights: Sequence[float] = (1.0,), hybrid_stride: int = 4,
                   spread: float | None = None, foreign_views: bool = False,
                   views_fix: Callable[[str, int], str] = lambda layout, count: f"--set views.layout={layout} --set "
                                                                                 f"views.count={count}",
                   ) -> tuple[list[Planner], list[str]]:
    """The named planners (registered ones, and ``module:function`` policies), and a message for
    each one skipped for want of a checkpoint (or, for one that plays a single view set, naming the
    calling command's way to run on it: ``views_fix(layout, count)``, by default the settings).
    ConfigError for a name not registered, listing those that are.

    ``checkpoints``: task (scores, regression, classification) -> checkpoint file (scores: also
    several, an ensemble), None for the released model of that task (``nbvtrain.release``) where
    there is one; ``hybrid`` takes the scores' and gives one planner per weight of
    ``hybrid_weights``. ``tta``: quarter-turn averaging for every learned planner; ``spread``: the
    spread rule's weight for regression and classification (``LearnedPlanner``); ``foreign_views``:
    the networks were trained on other candidate views (``LearnedPlanner``)."""
    context = PlannerContext(config, views, checkpoints, no_stall, tta, tuple(hybrid_weights), hybrid_stride, spread,
                             foreign_views)
    planners, skipped = [], []
    for name in names:
        if ":" in name:
            planners.append(PolicyPlanner(name, views))
            continue
        kind = PLANNERS.get(name)
        if kind is None:
            raise ConfigError(f"unknown planner {name!r}: choose from {', '.join(PLANNERS)}, or a policy module:function")
        try:
            planners += kind.build(context)
        except Skipped as reason:
            skipped.append(f"{name}: skipped, {reason.fix(views_fix(*reason.views) if reason.views else '')}")
    return planners, skipped
