"""Time per NBV of the planners of ``nbvtrain evaluate`` on this CPU, next to the paper's figures.

States come from real reconstructions (the shared bunny, or the built-in mug when ../shared is
absent; default settings: 176 x 144 sensor, 500 hemisphere views): random-planner runs of 10
scans from 3 starts give 27 observations. Each planner's ``next_pose`` is timed on every one.
Targets: regression <= 5 ms, information gain over 20 views <= 0.3 s (issue 5), the candidate-score
networks <= 5 ms (issue 14; the released one when there is one, and an untrained nbvscore-3).

The baseline for information gain, in the same process, is the same walk done the plain way
(``sampled_scores`` of tests/reference_infogain.py: sample each ray densely with numpy); it is
timed on a subset of rays and scaled to all rays of the 20 views.

    python benchmarks/evaluate.py [--mesh FILE] [--threads 2]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np
import torch

from nbvdata.core.config import SimConfig
from nbvdata.simulation.episode import Reconstruction, scene_rng
from nbvdata.simulation.mesh import load_mesh
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.shapes import builtin_object
from nbvtrain.networks.config import TrainConfig
from nbvtrain.networks.models import build_model
from nbvtrain.networks.train import save_training_state
from nbvtrain.planners import InfoGainPlanner, LearnedPlanner, Observation, OraclePlanner, RandomPlanner
from nbvtrain.planners.released import NoReleasedModel, released_checkpoint

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from reference_infogain import sampled_scores  # noqa: E402  (the tests' slow reference)

BUNNY = Path(__file__).resolve().parents[2] / "shared" / "meshes" / "test" / "bunny_hr__odedstein.obj"
PAPER = {"regression": "0.3 s (GTX 1080)", "infogain": "29.9 s", "classification": "0.01 s"}


def observations(scene: Scene, starts: int = 3, scans: int = 10) -> list[tuple[Observation, Reconstruction]]:
    """States after 1..scans-1 scans of random-planner runs (each with its simulation state)."""
    states = []
    for start in range(starts):
        planner = RandomPlanner(scene.views)
        planner.start(start)
        state = Reconstruction(scene, None, np.random.default_rng(start))
        poses = [scene.views[start * 97 % len(scene.views)]]
        state.scan_pose(poses[0])
        for _ in range(scans - 1):
            observation = Observation(state.grid.probabilities(), tuple(poses))
            states.append((observation, state))
            poses.append(planner.next_pose(observation))
            state = _copy(state)
            state.scan_pose(poses[-1])
    return states


def _copy(state: Reconstruction) -> Reconstruction:
    twin = Reconstruction(state.scene, None, state.rng)
    twin.grid.log_odds[...], twin.grid.observed[...] = state.grid.log_odds, state.grid.observed
    twin.covered, twin.scans = state.covered.copy(), state.scans
    return twin


def median_ms(planner, states) -> float:
    times = []
    for observation, state in states:
        started = time.perf_counter()
        planner.next_pose(observation, state if planner.privileged else None)
        times.append(time.perf_counter() - started)
    return 1e3 * float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", type=Path, default=BUNNY if BUNNY.exists() else None)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    numba.set_num_threads(args.threads)
    config = SimConfig()
    obj = load_mesh(args.mesh, config.mesh) if args.mesh else builtin_object("mug", config.mesh)
    scene = Scene.build(obj, config, scene_rng(0, obj.mesh_id))
    states = observations(scene)
    with tempfile.TemporaryDirectory() as tmp:
        checkpoint = Path(tmp) / "nbvnet-4-5.pt"
        torch.manual_seed(0)
        model = build_model("nbvnet-4-5")
        save_training_state(checkpoint, model, torch.optim.Adam(model.parameters()), TrainConfig(), [], 0, config.views.radius)
        regression = LearnedPlanner(checkpoint, config.views.radius, "regression")
        scores = {}
        for name in ("nbvscore-fc3", "nbvscore-3"):
            path = Path(tmp) / f"{name}.pt"
            model = build_model(name, views=scene.views.unit_positions)
            save_training_state(path, model, torch.optim.Adam(model.parameters()), TrainConfig(model=name), [], 0,
                  config.views.radius, None, scene.views.unit_positions)
            scores[f"scores ({name})"] = (LearnedPlanner(path, config.views.radius, "scores", scene.views), 5.0)
        try:
            released = released_checkpoint("scores")
            scores["scores (released)"] = (LearnedPlanner(released, config.views.radius, "scores", scene.views), 5.0)
        except NoReleasedModel:
            pass
    infogain = InfoGainPlanner(config.scene_grid, config.sensor, config.views.radius, config.mesh.object_size,
                               config.oracle.min_overlap)
    planners = {"regression": (regression, 5.0), **scores, "infogain": (infogain, 300.0),
                "oracle": (OraclePlanner(scene.views, config.oracle.min_overlap), None)}
    print(f"{obj.source}: {len(states)} states, {config.sensor.width} x {config.sensor.height} sensor, "
          f"{args.threads} threads; median time per NBV")
    print(f"{'planner':26s} {'ms':>9s} {'target':>8s}  paper")
    medians = {}
    for name, (planner, target) in planners.items():
        ms = medians[name] = median_ms(planner, states)
        verdict = "" if target is None else f"{target:6.0f} ms {'met' if ms <= target else 'NOT met'}"
        print(f"{name:26s} {ms:9.2f} {verdict:>16s}  {PAPER.get(name, '-')}")

    rays = np.arange(0, infogain._ends.shape[1], 97)
    observation = states[len(states) // 2][0]
    started = time.perf_counter()
    sampled_scores(infogain, observation.probabilities, 0, rays)
    per_ray = (time.perf_counter() - started) / len(rays)
    baseline = 1e3 * per_ray * infogain._ends.shape[0] * infogain._ends.shape[1]
    fast = medians["infogain"]
    print(f"information gain, numpy sampled walk (baseline, {len(rays)} rays timed, scaled to "
          f"{infogain._ends.shape[0]} x {infogain._ends.shape[1]} rays): {baseline:,.0f} ms; "
          f"numba DDA {fast:.1f} ms: {baseline / fast:,.0f}x")


if __name__ == "__main__":
    main()
