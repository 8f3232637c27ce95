"""The next-best-view planners, one family a module, and their registry.

One interface (``planner.next_pose(observation) -> Pose``) and one registry (``base``:
``PLANNERS``, which ``build_planners``, the CLI's check, the docs' table and the tests are made from).

A planner decides from what a real robot has, an ``Observation``: the occupancy grid and the
poses scanned so far. Only the oracle is privileged: it is also handed the simulation's
``Reconstruction`` (which knows the mesh) and is an upper bound, not a method.

- ``scores``: a trained candidate-score network (``nbvscore-*``); the candidate view with the
  highest score among those not scanned yet (a scanned pose marks its nearest candidate view,
  ``nbvdata.core.views.scanned_views``), so it never repeats a view. Several checkpoints are an
  ensemble: the mean of their scores, each standardised over the unscanned views
  (``nbvtrain.networks.scores.standardise``), so every network has one vote whatever the scale of its
  scores (their losses fix them only up to a shift, and their sharpness grows with training).
- ``regression``: a trained NBV-net; its output direction, taken as it is (not snapped to a
  candidate), at the view sphere's radius, looking at the centre (``nbvtrain.networks.predict``).
- ``classification``: NBV-Net's 14 fixed views; the chosen class's position.
- With ``spread`` W (``nbvtrain evaluate --spread W``), regression and classification take the
  unscanned candidate view v with the highest cos(answer, v) - W cos(v, its nearest scan)
  (``nbvdata.core.views.spread_view``): their answer spread away from what was scanned; it never
  repeats a view. W = 0 is the unscanned view nearest the answer.
- With ``no_stall`` (``nbvtrain evaluate --no-stall``), regression and classification do not
  repeat a scan: when the candidate view nearest to their pose is one a scan already marked,
  classification takes its next most likely class that repeats nothing, regression (and
  classification when every class repeats) the candidate view nearest to its output that was
  not scanned. Off (the default) is the paper's behaviour.
- ``infogain``: Kriegel et al. 2012, exhaustive over 20 views spread like the candidate views
  (``views.layout``: the upper hemisphere by default, as the authors' data): every sensor
  ray walks the grid from the sensor (OctoMap's DDA, as the integration) until the first
  occupied voxel (p > 0.5) or the sensor's far range, adding the entropy H(p) of every unknown
  voxel it passes inside the object's box. A view must pass the overlap constraint, estimated
  from the grid: of its rays that reach the box and meet a non-free voxel there, the share whose
  first such voxel is known occupied (surface seen before) must be >= ``min_overlap``; when no
  view passes, the most informative view is taken (as the oracle does).
- ``oracle``: the exhaustive ground truth of ``nbvdata.simulation.oracle`` over every candidate view; once no
  view adds anything at the scene's match distance, ``farthest``'s view.
- ``viewrank``: a ranker of per-view features (``nbvtrain.ranking.viewrank``, ``RankerPlanner``) on any view set.
- ``occlusion-aware``, ``unobserved-voxel``, ``rear-side-voxel``, ``rear-side-entropy``,
  ``proximity-count``, ``average-entropy``, ``area-factor``, ``proximity-shadow``: the field's hand-crafted metrics over
  every candidate view (``nbvdata.simulation.viewfeatures.METRICS``, ``MetricPlanner``); ``expected-surface``: the
  surface a learned prior expects each view to newly see (``SurfacePlanner``, ``--surface-prior``).
- ``setcover``: SCVP's one-shot plan, privileged like the oracle: at its first decision it
  solves the state's set cover (``nbvdata.simulation.setcover``, the fewest views that cover the rest) once,
  then scans the planned views in the order of the shortest tour from where the sensor is
  (``nbvdata.core.paths.shortest_tour``, round the object's bounding sphere: MA-SCVP's point, a
  shorter path); with the plan done (everything observable covered) it takes the view adding
  the most, as the oracle without the overlap rule. The overlap rule is no part of the plan, as
  in SCVP.
- ``random``: a seeded uniformly random candidate view.
- ``farthest``: the unscanned candidate view farthest in angle from every pose scanned so far
  (greedy farthest-point sampling of the view sphere). It reads neither the grid nor the mesh:
  what spreading the views alone covers, the baseline that shows whether a planner's grid
  reading adds anything to that.
- ``module:function`` (or ``path/to/file.py:function``): a policy on the observation of the
  reconstruction environment ``nbvdata.env`` (``PolicyPlanner``), e.g. one trained by RL.
- ``hybrid``: the score network's standardised scores plus ``weight`` times the standardised
  information gain of every unscanned candidate view (``HybridPlanner``; 0 for a view that fails
  the overlap estimate or adds nothing, as the networks' targets give a view that breaks the
  overlap rule), from an image ``stride`` times coarser than the sensor's (the same field of
  view): weight 0 is the network's choice, a large weight information gain's among the valid views.
- ``tta`` (``nbvtrain evaluate --tta``): a learned planner averages its network's answers over
  the four quarter turns about z where that is exact (``nbvtrain.networks.predict.Predictor``).

Modules: ``base`` (observation, interface, registry), ``builder`` (``build_planners``), ``networks``, ``infogain``,
``reference`` (oracle, setcover, random, farthest), ``ranker``, ``metrics``, ``covers``,
``hybrid``, ``wrappers`` (snapped, travel), ``policies`` (``module:function``), ``provider`` (what
``nbvdata generate --policy`` follows), ``released`` (the models shipped with the package).
Importing the package registers every family, in the docs' order.
"""

# isort: off
# The families in the docs' order: importing each registers its planners, and PLANNERS keeps that
# order (the docs' table, evaluate's default list).
from nbvtrain.planners.base import (PLANNERS, READS, Observation, Planner, PlannerContext, PlannerKind, Skipped,
                                    default_planners, planner_table, register_planner, robot_radius)
from nbvtrain.planners.networks import LearnedPlanner
from nbvtrain.planners.infogain import InfoGainPlanner, InfoGainScores
from nbvtrain.planners.reference import FarthestPlanner, OraclePlanner, RandomPlanner, SetCoverPlanner
from nbvtrain.planners.ranker import RankerPlanner
from nbvtrain.planners.metrics import MetricPlanner, SurfacePlanner
from nbvtrain.planners.covers import CoverModelPlanner, CoverPlanner, SCVPNetPlanner, fixed_layout
from nbvtrain.planners.hybrid import HybridPlanner
from nbvtrain.planners.wrappers import SnappedPlanner, TravelPlanner
from nbvtrain.planners.policies import PolicyPlanner, policy_function
from nbvtrain.planners.builder import build_planners
# isort: on

__all__ = ["PLANNERS", "READS", "CoverModelPlanner", "CoverPlanner", "FarthestPlanner", "HybridPlanner",
           "InfoGainPlanner", "InfoGainScores", "LearnedPlanner", "MetricPlanner", "Observation", "OraclePlanner",
           "Planner", "PlannerContext", "PlannerKind", "PolicyPlanner", "RandomPlanner", "RankerPlanner",
           "SCVPNetPlanner", "SetCoverPlanner", "Skipped", "SnappedPlanner", "SurfacePlanner", "TravelPlanner",
           "build_planners", "default_planners", "fixed_layout", "planner_table", "policy_function",
           "register_planner", "robot_radius"]
