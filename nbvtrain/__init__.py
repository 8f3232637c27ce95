"""nbvtrain: the NBV-net family trained on nbvdata shards, rankers and set-cover models of per-view
features, the planners, closed-loop evaluation and the field's benchmark, and a robot's planning.

Folders are the stages, data flowing one way (docs/design.md, tests/test_layout.py): ``networks``
< ``ranking`` < ``planners`` < ``evaluation`` < ``robot``, with ``release`` and ``cli`` on top.
Old module paths (before 0.2) still import, with a DeprecationWarning (``nbvdata.core.moved``).
"""

from nbvdata.core.moved import install

__version__ = "0.1.0"

MOVED = {
    "nbvtrain._lightgbm": "nbvtrain.ranking._lightgbm",
    "nbvtrain.baselines": "nbvtrain.networks.baselines",
    "nbvtrain.benchmark": "nbvtrain.evaluation.benchmark",
    "nbvtrain.benchmark_report": "nbvtrain.evaluation.benchmark_report",
    "nbvtrain.checkpoint": "nbvtrain.networks.checkpoint",
    "nbvtrain.config": "nbvtrain.networks.config",
    "nbvtrain.covermodel": "nbvtrain.ranking.covermodel",
    "nbvtrain.covernet": "nbvtrain.ranking.covernet",
    "nbvtrain.data": "nbvtrain.networks.training_data",
    "nbvtrain.dataset": "nbvtrain.networks.dataset",
    "nbvtrain.evaluate": "nbvtrain.evaluation.evaluate",
    "nbvtrain.metrics": "nbvtrain.networks.metrics",
    "nbvtrain.models": "nbvtrain.networks.models",
    "nbvtrain.plan": "nbvtrain.robot.plan",
    "nbvtrain.policy": "nbvtrain.planners.provider",
    "nbvtrain.predict": "nbvtrain.networks.predict",
    "nbvtrain.rankdata": "nbvtrain.ranking.rankdata",
    "nbvtrain.rankfit": "nbvtrain.ranking.rankfit",
    "nbvtrain.rl": "nbvtrain.networks.rl",
    "nbvtrain.scene": "nbvtrain.networks.trained_scene",
    "nbvtrain.scores": "nbvtrain.networks.scores",
    "nbvtrain.sensordata": "nbvtrain.robot.sensordata",
    "nbvtrain.statistics": "nbvtrain.evaluation.statistics",
    "nbvtrain.surfaceprior": "nbvtrain.ranking.surfaceprior",
    "nbvtrain.train": "nbvtrain.networks.train",
    "nbvtrain.trained_scene": "nbvtrain.networks.trained_scene",
    "nbvtrain.training_data": "nbvtrain.networks.training_data",
    "nbvtrain.trees": "nbvtrain.ranking.trees",
    "nbvtrain.viewrank": "nbvtrain.ranking.viewrank",
}
"""Old module path -> new module path, nbvtrain's."""
install(MOVED)
