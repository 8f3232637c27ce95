"""Stable-Baselines3 PPO on ``nbvdata/Reconstruct-v0``: trains on four built-in shapes, then
compares it with a random, a farthest-view and the greedy-oracle policy on the two built-in shapes
held out.

    pip install -e ".[rl]" && pip install stable-baselines3 --no-deps  # SB3 on the torch installed
    python examples/ppo_sb3.py --timesteps 20000 --minutes 30

The policy: a plain MLP on the view state (``taken``, which views were scanned) and a pooled
grid (the occupied and unknown voxels, each averaged over 4^3 blocks: 2 x 8^3 values). Training
stops at ``--timesteps`` environment steps or after ``--minutes`` of this process's CPU time
(all its threads), whichever comes first: the same budget on an idle and on a loaded machine. The evaluation runs ``--starts`` episodes per held-out shape (seeded start views, the same
for every policy) and prints each policy's mean coverage after its last scan (of all the
reference points, and of those some candidate view sees). PPO is evaluated twice: its own
deterministic action, and the most probable action among the views not scanned yet (a repeat
adds nothing, and a short training run has not learnt that everywhere).

The trained model is saved to ``--out``; ``policy`` below runs it on the environment's
observation, so ``nbvtrain evaluate`` can put it in one table with the other planners:

    NBV_PPO_MODEL=runs/ppo_sb3/model.zip nbvtrain evaluate --meshes MESHES \\
        --planners examples/ppo_sb3.py:policy,oracle,random

Not part of the test suite: minutes of CPU time, and stable-baselines3 is no dependency.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

import gymnasium
import nbvdata.env  # noqa: F401  (registers nbvdata/Reconstruct-v0)
from nbvdata.views import farthest_view

TRAIN_SHAPES = ["builtin:mug", "builtin:table_lamp", "builtin:step_block", "builtin:snowman"]
HELD_OUT = ["builtin:ring", "builtin:pill"]
POOL = 4


class PooledGrid(BaseFeaturesExtractor):
    """(occupied, unknown) voxels averaged over POOL^3 blocks, and the view state, through one
    hidden layer: (B, n, n, n) grid and (B, V) taken -> (B, features)."""

    def __init__(self, observation_space: gymnasium.spaces.Dict, features: int = 256):
        super().__init__(observation_space, features)
        n, views = observation_space["grid"].shape[0], observation_space["taken"].n
        self.pool = nn.AvgPool3d(POOL)
        self.body = nn.Sequential(nn.Linear(2 * (n // POOL) ** 3 + views, features), nn.ReLU())

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        grid = observations["grid"]
        channels = torch.stack([(grid > 0.5).float(), (grid == 0.5).float()], dim=1)
        return self.body(torch.cat([self.pool(channels).flatten(1), observations["taken"].float()], dim=1))


class CpuClock(BaseCallback):
    """Stops training after ``minutes`` of this process's CPU time."""

    def __init__(self, minutes: float):
        super().__init__()
        self.deadline = time.process_time() + 60 * minutes

    def _on_step(self) -> bool:
        return time.process_time() < self.deadline


def masked_choice(model: PPO, observation: dict) -> int:
    """The policy's most probable view among those not scanned yet (``taken`` == 0)."""
    tensor, _ = model.policy.obs_to_tensor(observation)
    with torch.no_grad():
        probabilities = model.policy.get_distribution(tensor).distribution.probs[0].numpy()
    probabilities[np.asarray(observation["taken"]) != 0] = -1.0
    return int(np.argmax(probabilities))


def evaluate(env, choose, starts: int) -> tuple[float, float]:
    """Mean (coverage, observable coverage) after the last scan over ``starts`` episodes per
    held-out shape; ``choose(observation, info, rng)`` gives each action."""
    finals = []
    for mesh in HELD_OUT:
        for start in range(starts):
            rng = np.random.default_rng(start)
            observation, info = env.reset(seed=start, options={"mesh": mesh})
            done = False
            while not done:
                observation, _, terminated, truncated, info = env.step(choose(observation, info, rng))
                done = terminated or truncated
            finals.append((info["coverage"], info["observable_coverage"]))
    return tuple(np.mean(finals, axis=0))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=20_000, help="environment steps to train at most (20000)")
    parser.add_argument("--minutes", type=float, default=30.0, help="CPU minutes to train at most (30)")
    parser.add_argument("--starts", type=int, default=10, help="evaluation episodes per held-out shape (10)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="a simulation setting, as nbvdata generate --set (default: the default scene)")
    parser.add_argument("--out", type=Path, default=Path("runs/ppo_sb3"), help="folder for model.zip")
    args = parser.parse_args()
    torch.set_num_threads(1)
    train = gymnasium.make("nbvdata/Reconstruct-v0", meshes=TRAIN_SHAPES, overrides=args.overrides)
    model = PPO("MultiInputPolicy", train, n_steps=512, batch_size=128, n_epochs=4, learning_rate=3e-4, gamma=0.99,
                ent_coef=0.01, seed=args.seed, device="cpu", verbose=0,
                policy_kwargs={"features_extractor_class": PooledGrid, "net_arch": {"pi": [256], "vf": [256]}})
    began, began_cpu = time.perf_counter(), time.process_time()
    model.learn(total_timesteps=args.timesteps, callback=CpuClock(args.minutes))
    trained, trained_cpu = time.perf_counter() - began, time.process_time() - began_cpu
    args.out.mkdir(parents=True, exist_ok=True)
    model.save(args.out / "model.zip")
    print(f"PPO: {model.num_timesteps} steps in {trained_cpu / 60:.1f} CPU min ({trained / 60:.1f} min wall, "
          f"{model.num_timesteps / trained_cpu:.1f} steps per CPU second); saved {args.out / 'model.zip'}")
    test = gymnasium.make("nbvdata/Reconstruct-v0", meshes=HELD_OUT, overrides=args.overrides, info_scores=True)
    views = test.action_space.n
    units = test.unwrapped.views.unit_positions
    policies = {
        "PPO": lambda observation, info, rng: int(model.predict(observation, deterministic=True)[0]),
        "PPO, scanned views masked": lambda observation, info, rng: masked_choice(model, observation),
        "random": lambda observation, info, rng: int(rng.integers(views)),
        "farthest (no grid)": lambda observation, info, rng: farthest_view(units, units[observation["taken"] != 0]),
        "greedy oracle": lambda observation, info, rng: max(info["nbv"], 0),
    }
    print(f"held-out shapes {', '.join(HELD_OUT)}, {args.starts} starts each; mean after the last scan:")
    print("| policy | coverage % | observable coverage % |\n|---|---|---|")
    for name, choose in policies.items():
        coverage, observable = evaluate(test, choose, args.starts)
        print(f"| {name} | {100 * coverage:.1f} | {100 * observable:.1f} |")


_MODEL = None


def policy(observation: dict) -> int:
    """The saved model (``NBV_PPO_MODEL``, default runs/ppo_sb3/model.zip) on one observation, its
    most probable view not scanned yet, for ``nbvtrain evaluate --planners examples/ppo_sb3.py:policy``."""
    global _MODEL
    if _MODEL is None:
        _MODEL = PPO.load(os.environ.get("NBV_PPO_MODEL", "runs/ppo_sb3/model.zip"), device="cpu")
    return masked_choice(_MODEL, observation)


if __name__ == "__main__":
    main()
