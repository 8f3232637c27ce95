"""``module:function`` (or ``path/to/file.py:function``): a policy on the observation of the
reconstruction environment ``nbvdata.env`` (``PolicyPlanner``), e.g. one trained by RL.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys
from pathlib import Path

import numpy as np

from nbvdata.core.config import ConfigError
from nbvdata.core.views import Pose, ViewSet, scanned_views
from nbvdata.simulation.episode import Reconstruction
from nbvtrain.planners.base import Observation, Planner


class PolicyPlanner(Planner):
    """A policy on the environment's observation (``nbvdata.env``), named ``module:function`` or
    ``path/to/file.py:function``: ``function(observation) -> action``.

    observation : dict, as ``nbvdata.env.ReconstructEnv`` returns it: ``grid`` (n, n, n) float32
        occupancy probabilities (0.5 = unknown), ``taken`` (V,) int8 candidate views scanned (a
        pose marks its nearest view)
    action : a candidate view index (an integer, as ``action="view"``) or a (3,) direction from
        the object centre (as ``action="pose"``; the sensor goes there on the view sphere)

    The function is called once per decision, in a fixed order, and is given no seed: a
    stochastic policy seeds itself. The module is imported with the working folder on the path.
    """

    def __init__(self, spec: str, views: ViewSet):
        try:
            import nbvdata.env  # noqa: F401  (gymnasium, the optional extra [rl])
        except ImportError as error:
            raise ConfigError(f"--planners {spec}: {error}") from None
        self.name, self.views = spec, views
        self.policy = policy_function(spec)

    def __reduce__(self):
        """Pickled as its arguments: a worker process imports the function itself."""
        return type(self), (self.name, self.views)

    def next_pose(self, observation: Observation, truth: Reconstruction | None = None) -> Pose:
        from nbvdata.env import check_view, direction_pose
        from nbvdata.env import observation as env_observation

        taken = scanned_views(observation.positions, self.views.unit_positions)
        action = self.policy(env_observation(observation.probabilities, taken))
        returned = f"policy {self.name} returned"
        try:
            if np.ndim(action) == 0:
                return self.views[check_view(action, len(self.views), returned)]
            return direction_pose(action, self.views, returned)[1]
        except (TypeError, ValueError) as error:
            raise ConfigError(f"{error} (a policy returns a candidate view index or a (3,) direction)") from None


def policy_function(spec: str):
    """The function ``spec`` names, ``module:function`` or ``path/to/file.py:function``;
    ConfigError (one line, naming the fix) when it cannot be imported or is not callable."""
    module_name, _, function_name = spec.rpartition(":")
    if not module_name or not function_name:
        raise ConfigError(f"--planners {spec!r}: a policy is module:function or path/to/file.py:function")
    try:
        if module_name.endswith(".py"):
            path = Path(module_name).resolve()
            if not path.is_file():
                raise ConfigError(f"--planners {spec}: no such file {module_name}")
            name = f"nbvtrain_policy_{path.stem}"
            module = sys.modules.get(name)
            if module is None or getattr(module, "__file__", None) != str(path):
                module_spec = importlib.util.spec_from_file_location(name, path)
                module = importlib.util.module_from_spec(module_spec)
                sys.modules[name] = module
                try:
                    module_spec.loader.exec_module(module)
                except BaseException:
                    del sys.modules[name]  # half loaded: not kept for a second try
                    raise
        else:
            if os.getcwd() not in sys.path:
                sys.path.insert(0, os.getcwd())
            module = importlib.import_module(module_name)
    except ConfigError:
        raise
    except Exception as error:  # ImportError, or whatever the module raises while it loads
        raise ConfigError(f"--planners {spec}: cannot import {module_name} ({type(error).__name__}: "
                          f"{' '.join(str(error).split())[:200]}); put it on PYTHONPATH or give "
                          "path/to/file.py:function") from None
    function = getattr(module, function_name, None)
    if not callable(function):
        raise ConfigError(f"--planners {spec}: {module_name} has no function {function_name}")
    return function
