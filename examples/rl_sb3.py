"""Reinforcement learning that learns on a CPU: the greedy oracle's choices cloned, DAgger, then
MaskablePPO (sb3-contrib) on ``nbvdata/Reconstruct-v0``, in a fixed budget of CPU minutes.

    pip install -e ".[rl]"
    python examples/rl_sb3.py --minutes 60      # train-meshes 1.2.0: train on its train part, choose on val
    python examples/rl_sb3.py --manifest manifests/builtin-shapes-1.3.0.json --minutes 3 --episodes 4 --gammas 0.5

The first needs the meshes of train-meshes 1.2.0 (``--meshes``, default ../shared/meshes) and
says so in one line without them; the second runs on what a clone has, the built-in shapes (4 to
learn on, 1 to choose on), in 3 CPU minutes.

The policy is the score network (``nbvtrain.networks.rl.ScoreFeatures``, ``nbvscore-fc3``) started from
the released weights (``--init new``: from new ones) with a linear head over its 500 scores,
started at the identity: before any step it is the released score network's choice. Stages,
each from the one before, each's actor saved in ``--out`` as ``STAGE.pt``:

1. ``clone``: ``--episodes`` episodes of the oracle's (``info["nbv"]``) on the training meshes,
   cloned (cross-entropy of the masked logits with the oracle's view, ``nbvtrain.networks.rl.clone``);
2. ``dagger``: ``--dagger-rounds`` rounds of the learner's own episodes, labelled by the oracle,
   added and cloned again;
3. ``ppo-g{GAMMA}``: for every ``--gammas`` discount, MaskablePPO from the DAgger actor (reward:
   the observable coverage a scan gained; views scanned are masked, so no repeat).

Every stage is scored on the validation meshes (the real meshes of the val part, ``--val-meshes``
of them, ``--val-starts`` seeded starts each, the same for every stage): the mean AUC of the
coverage curve over 10 scans (PC-NBV's, as ``nbvtrain benchmark``) and the final coverage. The
stage with the best validation AUC is copied to ``actor.pt`` (a row ``viewrank (reference)``:
the ranker of per-view features, ``--ranker``, scored the same way - the bar; never a stage), the PPO run with the best to
``ppo.pt``. ``--minutes`` bounds this process's CPU time from its start, imports included (one
torch and one ray-casting thread; the same budget on an idle and a loaded machine): the
validations still to come are kept in hand (each as long as the longest so far), cloning may take
10 % of the rest, DAgger up to 35 % in all, the PPO runs share what is left equally. ``--scratch-minutes M`` adds, after the choice,
masked PPO from new weights with the best PPO run's discount for M more CPU minutes
(``scratch.pt``), the baseline the warm start has to beat. ``curve.csv``: the validation figures
against CPU minutes (``steps``: PPO's environment steps, or the states cloned).

The actors run as planners (``NBV_RL_DIR``, default runs/rl_sb3)::

    nbvtrain evaluate --meshes ../shared/meshes/test --planners examples/rl_sb3.py:policy,farthest,oracle
    nbvtrain benchmark --protocol paper --planners examples/rl_sb3.py:clone,examples/rl_sb3.py:policy,farthest

(``policy``: ``actor.pt``, the stage chosen; ``clone``, ``dagger`` (its last round), ``ppo`` (the
discount best on validation), ``scratch``: those stages.) tests/test_rl.py runs its pieces on a
tiny scene, and the whole recipe from a copy of a clone on the built-in shapes in a CPU budget of
seconds.
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch

try:
    from sb3_contrib import MaskablePPO
    from stable_baselines3.common.callbacks import BaseCallback
except ImportError:
    sys.exit('examples/rl_sb3.py needs sb3-contrib and stable-baselines3: pip install -e ".[rl]"')

from nbvdata.core.config import SimConfig
from nbvdata.core.errors import UserError
from nbvdata.core.text import plural
from nbvdata.core.views import view_sphere
from nbvdata.env import ReconstructEnv
from nbvdata.schema.manifest import load_manifest
from nbvdata.simulation.sources import find_part_meshes
from nbvtrain.evaluation.benchmark import auc
from nbvtrain.networks import rl
from nbvtrain.planners.released import released_checkpoint

ROOT = Path(__file__).resolve().parents[1]
SCANS = 10
CLONE = "python examples/rl_sb3.py --manifest manifests/builtin-shapes-1.3.0.json --minutes 3 --episodes 4 --gammas 0.5"
"""The recipe on what a clone has: the built-in shapes (4 to learn on, 1 to choose on), 3 CPU minutes."""


EXIT_MINUTES = 0.05
"""CPU minutes kept for the end: saving the chosen actor and the interpreter's exit (about 2 s seen)."""


class Budget:
    """This process's CPU minutes since it started (its imports included: what ``time`` reports),
    against deadlines; ``validation``: what one validation took, kept in hand for those still to come."""

    def __init__(self):
        self.validation = 0.0

    def minutes(self) -> float:
        return time.process_time() / 60

    def left(self, until: float) -> bool:
        return self.minutes() < until


class StopAt(BaseCallback):
    """Stops MaskablePPO once ``budget`` reaches ``until`` CPU minutes; every ``every`` CPU
    minutes ``report()`` is called (a validation point of the curve), where one fits before the stop.

    A rollout stopped part-way is dropped, but a full one is followed by PPO's update, which no
    callback can stop: the last step of a rollout stops unless an update (as long as the longest
    so far; before the first, twice the rollout's own collection) fits before ``until``."""

    def __init__(self, budget: Budget, until: float, every: float, report):
        super().__init__()
        self.budget, self.until, self.every, self.report = budget, until, every, report
        self.next = budget.minutes() + every
        self.update, self.rollout_began, self.update_began = 0.0, budget.minutes(), None

    def _on_rollout_start(self) -> None:
        now = self.budget.minutes()
        if self.update_began is not None:
            self.update = max(self.update, now - self.update_began)
        self.rollout_began = now

    def _on_rollout_end(self) -> None:
        self.update_began = self.budget.minutes()

    def _on_step(self) -> bool:
        now = self.budget.minutes()
        if now >= self.next and now + self.budget.validation < self.until:  # a report that fits before the stop
            self.report(self.num_timesteps)
            self.next = now = self.budget.minutes()
            self.next += self.every
        if self.model.rollout_buffer.pos + 1 >= self.model.rollout_buffer.buffer_size:  # an update comes next
            return now + (self.update or 2 * (now - self.rollout_began)) < self.until
        return now < self.until


def part_meshes(manifest: Path, meshes: Path, part: str, count: int) -> list[Path | str]:
    """The first ``count`` real meshes (not the procedural ones) of ``part`` of the manifest's
    mesh split, in the split's order: mesh files, and ``"builtin:NAME"`` for a built-in shape."""
    found = [mesh.path or mesh.source for mesh in find_part_meshes(load_manifest(manifest), part, meshes)
             if "pybullet_random_urdfs" not in str(mesh.path)]
    return found[:count] if count else found


def actor_logits(policy):
    """``logits(grids, taken)`` of a MaskablePPO policy built on ``ScoreFeatures`` (pi=[])."""
    def logits(grids: torch.Tensor, taken: torch.Tensor) -> torch.Tensor:
        features = policy.features_extractor({"grid": grids, "taken": taken})
        return policy.action_net(policy.mlp_extractor.forward_actor(features))
    return logits


def new_model(env, views: np.ndarray, checkpoint, gamma: float, lr: float, seed: int) -> MaskablePPO:
    model = MaskablePPO("MultiInputPolicy", env, learning_rate=lr, n_steps=256, batch_size=64, n_epochs=4,
                        gamma=gamma, gae_lambda=0.95, clip_range=0.2, ent_coef=0.0, target_kl=0.05, seed=seed,
                        device="cpu", verbose=0,
                        policy_kwargs={"features_extractor_class": rl.ScoreFeatures,
                                       "features_extractor_kwargs": {"views": views, "checkpoint": checkpoint},
                                       "net_arch": {"pi": [], "vf": [64]}, "ortho_init": False})
    rl.identity_head(model.policy.action_net)
    return model


def validate(env: ReconstructEnv, choose, meshes: int, starts: int) -> tuple[float, float]:
    """Mean (AUC, final coverage) over ``meshes`` x ``starts`` seeded episodes of ``choose(observation,
    mask) -> view`` (a policy's greedy masked choice), the curve held at its last value after an early end."""
    aucs, finals = [], []
    for mesh in range(meshes):
        for start in range(starts):
            observation, info = env.reset(seed=1000 * mesh + start, options={"mesh": mesh})
            curve, done = [info["coverage"]], False
            while not done and len(curve) < SCANS:
                observation, _, terminated, truncated, info = env.step(choose(observation, info["action_mask"]))
                curve.append(info["coverage"])
                done = terminated or truncated
            curve += [curve[-1]] * (SCANS - len(curve))
            aucs.append(auc(np.array(curve)))
            finals.append(curve[-1])
    return float(np.mean(aucs)), float(np.mean(finals))


def main() -> None:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()),
                                     epilog=f"from a clone (no ../shared/meshes), on the built-in shapes in 3 CPU "
                                     f"minutes: {CLONE}")
    parser.add_argument("--manifest", type=Path, default=ROOT / "manifests" / "train-meshes-1.2.0.json",
                        help="the published version whose train and val parts are learned and chosen on "
                        "(train-meshes-1.2.0; manifests/builtin-shapes-1.3.0.json: the built-in shapes)")
    parser.add_argument("--meshes", type=Path, default=ROOT.parent / "shared" / "meshes",
                        help="the folder the manifest's meshes lie in or below (../shared/meshes)")
    parser.add_argument("--config", type=Path, help="the scene's settings (default: the default scene, whose 500 "
                        "views the released network scores; configs/smoke.yaml, a tiny one, needs --init new)")
    parser.add_argument("--train-meshes", type=int, default=0, help="real train-part meshes to learn on (0: all)")
    parser.add_argument("--val-meshes", type=int, default=0, help="real val-part meshes to choose on (0: all)")
    parser.add_argument("--val-starts", type=int, default=2)
    parser.add_argument("--minutes", type=float, default=60.0, help="CPU minutes for the whole recipe (60)")
    parser.add_argument("--episodes", type=int, default=200, help="episodes per cloning or DAgger round (200)")
    parser.add_argument("--dagger-rounds", type=int, default=2)
    parser.add_argument("--epochs", type=int, default=3, help="cloning epochs per round (3)")
    parser.add_argument("--gammas", default="0.1,0.5,0.99", help="MaskablePPO discounts to try (0.1,0.5,0.99)")
    parser.add_argument("--lr", type=float, default=1e-5, help="MaskablePPO learning rate from the warm start")
    parser.add_argument("--init", choices=("released", "new"), default="released")
    parser.add_argument("--scratch-minutes", type=float, default=0.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--ranker", default="released", help="a ranker file (nbvtrain fit --model viewrank-*) scored "
                        "on the validation meshes beside the stages, as the bar they must clear; 'released' (default) "
                        "the package's, 'none' no such row")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--out", type=Path, default=Path("runs/rl_sb3"))
    args = parser.parse_args()
    gammas = [float(g) for g in args.gammas.split(",")]
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    budget = Budget()
    try:
        train_paths = part_meshes(args.manifest, args.meshes, "train", args.train_meshes)
        val_paths = part_meshes(args.manifest, args.meshes, "val", args.val_meshes)
        train = ReconstructEnv(train_paths, args.config, args.overrides, info_scores=True, scene_cache=None)
        val = ReconstructEnv(val_paths, args.config, args.overrides, scene_cache=None)
    except UserError as error:
        sys.exit(f"examples/rl_sb3.py: {error}; or learn on the built-in shapes a clone has: {CLONE}")
    views = train.views.unit_positions
    checkpoint = released_checkpoint("scores") if args.init == "released" else None
    if checkpoint is not None and len(views) != len(view_sphere(SimConfig().views)):
        sys.exit(f"examples/rl_sb3.py: the scene has {len(views)} candidate views, the released score network scores "
                 f"the default scene's {len(view_sphere(SimConfig().views))}: pass --init new, or drop --config/--set")
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"{plural(len(train_paths), 'training mesh')}, {plural(len(val_paths), 'validation mesh')} x "
          f"{plural(args.val_starts, 'start')}; "
          f"{args.minutes:g} CPU minutes", flush=True)
    rows = []

    def record(stage: str, steps: int, logits=None, choose=None) -> tuple[float, float]:
        began = budget.minutes()
        figures = validate(val, choose or rl.greedy(logits), len(val_paths), args.val_starts)
        budget.validation = max(budget.validation, budget.minutes() - began)
        rows.append({"stage": stage, "cpu_minutes": round(budget.minutes(), 2), "steps": steps,
                     "val_auc": round(100 * figures[0], 2), "val_coverage": round(100 * figures[1], 2)})
        print(" | ".join(f"{k} {v}" for k, v in rows[-1].items()), flush=True)
        with open(args.out / "curve.csv", "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        return figures

    model = new_model(train, views, checkpoint, gammas[0], args.lr, args.seed)
    policy = model.policy
    parameters = list(policy.features_extractor.parameters()) + list(policy.action_net.parameters())
    logits = actor_logits(policy)
    results = {"start": record("start", 0, logits)}
    if args.ranker != "none":  # the ranker of per-view features (docs/viewrank.md): the bar, trained on no RL
        from nbvtrain.planners.released import NoReleasedModel, released_ranker
        from nbvtrain.ranking.viewrank import env_choice, load_ranker

        try:
            ranker = load_ranker(released_ranker() if args.ranker == "released" else Path(args.ranker))
            record("viewrank (reference)", 0, choose=env_choice(ranker, val.views, val.config))
        except NoReleasedModel as reason:
            print(f"examples/rl_sb3.py: no viewrank reference row: {reason}", flush=True)
    rl.save_actor(args.out / "start.pt", policy.features_extractor, policy.action_net, {"stage": "start"})

    def after_round(round_: int, data) -> None:
        stage = "clone" if round_ == 0 else f"dagger{round_}"
        results[stage] = record(stage, len(data), logits)
        rl.save_actor(args.out / f"{stage}.pt", policy.features_extractor, policy.action_net,
                      {"stage": stage, "states": len(data)})
        if round_ == args.dagger_rounds and round_:
            shutil.copyfile(args.out / f"{stage}.pt", args.out / "dagger.pt")

    # What is left once the validations still to come are kept in hand: one after each DAgger round, one
    # after each PPO run (a report inside a run fits before its stop, StopAt)
    learning = args.minutes - EXIT_MINUTES - budget.minutes() - budget.validation * (args.dagger_rounds + 1 + len(gammas))
    if learning <= 0:
        print(f"examples/rl_sb3.py: the budget of {args.minutes:g} CPU minutes is spent on imports, meshes and "
              f"validations ({budget.minutes():.2f} so far, {budget.validation:.2f} a validation): stages stop at once; "
              "give more --minutes", flush=True)
    start = budget.minutes()
    deadlines = [start + 0.10 * learning] + [start + 0.10 * learning + 0.25 * learning * r / args.dagger_rounds
                                             for r in range(1, args.dagger_rounds + 1)]
    rl.dagger(train, logits, parameters, args.dagger_rounds, args.episodes, args.epochs, args.seed, lr=1e-4,
              after_round=after_round, stop=lambda round_: not budget.left(deadlines[round_]))
    warm = {k: v.clone() for k, v in policy.state_dict().items()}
    share = max(0.0, (args.minutes - EXIT_MINUTES - budget.minutes() - budget.validation * len(gammas)) / len(gammas))
    for gamma in gammas:
        stage = f"ppo-g{gamma:g}"
        model = new_model(train, views, None, gamma, args.lr, args.seed)
        model.policy.load_state_dict(warm)
        logits = actor_logits(model.policy)
        until = budget.minutes() + share
        model.learn(10**9, callback=StopAt(budget, until, max(share / 4, 0.5),
                                           lambda steps: record(stage, steps, logits)))
        results[stage] = record(stage, model.num_timesteps, logits)
        rl.save_actor(args.out / f"{stage}.pt", model.policy.features_extractor, model.policy.action_net,
                   {"stage": stage, "gamma": gamma, "steps": model.num_timesteps})
    best = max(results, key=lambda stage: results[stage][0])  # validation AUC
    shutil.copyfile(args.out / f"{best}.pt", args.out / "actor.pt")
    best_ppo = max((stage for stage in results if stage.startswith("ppo-g")), key=lambda stage: results[stage][0])
    shutil.copyfile(args.out / f"{best_ppo}.pt", args.out / "ppo.pt")
    print(f"chosen on validation: {best} (AUC {100 * results[best][0]:.2f} %); {budget.minutes():.1f} CPU minutes; "
          f"saved {args.out / 'actor.pt'}", flush=True)
    if args.scratch_minutes > 0:
        gamma = float(best_ppo.removeprefix("ppo-g"))
        model = new_model(train, views, None, gamma, 3e-4, args.seed)
        logits = actor_logits(model.policy)
        until = budget.minutes() + args.scratch_minutes
        model.learn(10**9, callback=StopAt(budget, until, max(args.scratch_minutes / 4, 0.5),
                                           lambda steps: record("scratch", steps, logits)))
        record("scratch", model.num_timesteps, logits)
        rl.save_actor(args.out / "scratch.pt", model.policy.features_extractor, model.policy.action_net,
                   {"stage": "scratch", "gamma": gamma, "steps": model.num_timesteps})


_ACTORS: dict[Path, object] = {}


def _act(stage: str, observation: dict) -> int:
    """The saved actor of ``stage`` on one observation: its most probable view not scanned yet."""
    path = Path(os.environ.get("NBV_RL_DIR", "runs/rl_sb3")) / f"{stage}.pt"
    if path not in _ACTORS:
        _ACTORS[path] = rl.greedy(rl.load_actor(path)[0])
    return _ACTORS[path](observation, np.asarray(observation["taken"]) == 0)


def policy(observation: dict) -> int:
    """The actor chosen on validation (actor.pt), for ``nbvtrain evaluate --planners``."""
    return _act("actor", observation)


def clone(observation: dict) -> int:
    """The behaviour-cloning stage's actor (clone.pt)."""
    return _act("clone", observation)


def dagger(observation: dict) -> int:
    """The last DAgger round's actor (dagger.pt)."""
    return _act("dagger", observation)


def ppo(observation: dict) -> int:
    """The MaskablePPO actor of the discount best on validation (ppo.pt)."""
    return _act("ppo", observation)


def scratch(observation: dict) -> int:
    """Masked PPO from new weights (scratch.pt)."""
    return _act("scratch", observation)


if __name__ == "__main__":
    main()
