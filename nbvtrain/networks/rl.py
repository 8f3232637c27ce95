"""Learning a policy on ``nbvdata/Reconstruct-v0``: the score network as the policy's body,
behaviour cloning and DAgger from the greedy oracle, and the saved actor that planners run.

``ScoreFeatures`` is a Stable-Baselines3 features extractor (it needs no SB3 to import): a score
network (``nbvscore-fc3``; the released weights, or new ones) that turns the observation into one
score per candidate view; with ``net_arch=dict(pi=[], vf=[...])`` the actor's logits are a linear
map of the scores (``identity_head`` starts it at the scores themselves), so the warm-started
policy begins as the released network's choice. ``save_actor`` / ``load_actor`` keep the actor
(network and head) as tensors only, loaded with ``weights_only=True``: no pickled code.

The environment gives the oracle's next-best-view at every state (``info_scores=True``:
``info["nbv"]``), so a demonstration costs one environment step and its label nothing more.

- ``collect`` runs episodes and keeps every state the agent decided at with the oracle's choice
  there; who acts is drawn per step: the oracle with probability ``expert_share``, else the
  learner (``expert_share=1``: behaviour cloning's data; ``0``: a DAgger round, the learner's own
  states labelled by the oracle; Ross et al. 2011).
- ``clone`` fits a policy's logits to the labels: cross-entropy of the masked logits (views the
  mask leaves out get -inf) with the oracle's choice.
- ``dagger`` is the loop: a round of the oracle's demonstrations, cloned; then rounds of the
  learner's, added to the data and cloned again.

A policy is ``logits(grids, taken) -> (B, V)``: grids (B, n, n, n) float32 occupancy
probabilities, taken (B, V) float32 view states, as the environment's observation; its
parameters are those ``clone`` trains. A Stable-Baselines3 policy (``examples/rl_sb3.py``), the
score networks (``nbvtrain.networks.models.ScoreNet``: the same input) or any torch module fit. No
library fits better: ``imitation`` (1.0) wants its own rollout types and SB3 policies only, and
labels states by calling an expert policy, where here the label is already in ``info``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
import torch
from torch import nn
from torch.nn import functional

from nbvtrain.networks.checkpoint import (WEIGHTS_KEY, CheckpointError, check_weights, load_checkpoint, model_from,
                                          weights_digest)
from nbvtrain.networks.models import ScoreNet, build_model

Logits = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
Choose = Callable[[dict, np.ndarray], int]  # (observation, action mask) -> view
LEVELS = 254  # grid probabilities kept as uint8 round(p * 254): 0.5 (unknown) exactly 127
SCORE_MODEL = "nbvscore-fc3"


def score_network(views: np.ndarray, checkpoint: str | Path | None = None, dropout_from: str = "fc1") -> ScoreNet:
    """A score network for (V, 3) candidate view directions ``views``, its dropout at 0 (a policy
    acts and learns with the same network): the weights of ``checkpoint`` (a score network's, for
    the same views), or new ones (None) with dropout layers after ``dropout_from``."""
    views = np.asarray(views, dtype=np.float64)
    if checkpoint is None:
        network = build_model(SCORE_MODEL, dropout_from, 0.0, views=views)
        network.dropout_from = dropout_from
        return network
    state = load_checkpoint(checkpoint)
    trained = model_from(state, Path(checkpoint))
    units = state["view_units"].double().numpy()
    if state["model"] != SCORE_MODEL or units.shape != views.shape or not np.allclose(units, views, atol=1e-6):
        raise CheckpointError(f"{checkpoint}: not an {SCORE_MODEL} network for these {len(views)} candidate views "
                              f"(it is {state['model']} for {len(units)}): pass one trained on this scene's views, "
                              "or none to start from new weights")
    for module in trained.modules():
        if isinstance(module, nn.Dropout):
            module.p = 0.0
    trained.dropout_from = state["config"].get("dropout_from", "conv3")
    return trained


class ScoreFeatures(nn.Module):
    """Observation {"grid": (B, n, n, n), "taken": (B, V)} -> (B, V) scores of a score network
    (``score_network(views, checkpoint)``); ``features_dim`` = V, as SB3 reads it."""

    def __init__(self, observation_space, views: np.ndarray, checkpoint: str | Path | None = None):
        super().__init__()
        self.network = score_network(views, checkpoint)
        self.views = np.asarray(views, dtype=np.float64)
        self.features_dim = self.network.views
        if observation_space["taken"].n != self.features_dim:
            raise ValueError(f"the environment has {observation_space['taken'].n} candidate views, the score network "
                             f"{self.features_dim}: give views= the environment's (env.unwrapped.views.unit_positions)")

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        return self.network(observations["grid"].float()[:, None], observations["taken"].float())


def identity_head(head: nn.Linear, scale: float = 1.0) -> None:
    """Set a (V -> V) linear head to ``scale`` x the identity: logits = scale x scores."""
    with torch.no_grad():
        head.weight.copy_(scale * torch.eye(head.out_features, head.in_features))
        head.bias.zero_()


def save_actor(path: str | Path, features: ScoreFeatures, head: nn.Linear, about: dict) -> None:
    """The actor (score network and head) as tensors, with ``about`` (plain values: the stage,
    its settings, its validation figures)."""
    network, head = features.network.state_dict(), head.state_dict()
    torch.save({"kind": "nbvtrain.networks.rl actor", "model": SCORE_MODEL, "views": torch.from_numpy(features.views),
                "dropout_from": features.network.dropout_from, "network": network, "head": head, "about": about,
                WEIGHTS_KEY: weights_digest(network, head)}, path)


def load_actor(path: str | Path) -> tuple[Logits, dict]:
    """(``logits(grids, taken)``, about) of an actor ``save_actor`` wrote; CheckpointError in one
    line for anything else."""
    path = Path(path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise CheckpointError(f"{path}: no such file; train one with python examples/rl_sb3.py") from None
    except Exception as error:  # noqa: BLE001  (a damaged or foreign file: one line)
        raise CheckpointError(f"{path}: not an actor saved by nbvtrain.networks.rl ({type(error).__name__}); train one with "
                              "python examples/rl_sb3.py") from None
    if not isinstance(state, dict) or state.get("kind") != "nbvtrain.networks.rl actor":
        raise CheckpointError(f"{path}: not an actor saved by nbvtrain.networks.rl; train one with python examples/rl_sb3.py")
    check_weights(state, path, "train one with python examples/rl_sb3.py", "network", "head")
    try:
        network = score_network(state["views"].double().numpy(), dropout_from=state["dropout_from"])
        network.load_state_dict(state["network"])
        head = nn.Linear(network.views, network.views)
        head.load_state_dict(state["head"])
    except (KeyError, AttributeError, TypeError, ValueError, RuntimeError) as error:
        raise CheckpointError(f"{path}: a damaged actor ({type(error).__name__}: {str(error)[:120]}); train it "
                              "again with python examples/rl_sb3.py") from None
    network.eval()

    def logits(grids: torch.Tensor, taken: torch.Tensor) -> torch.Tensor:
        return head(network(grids[:, None], taken))
    return logits, state["about"]


@dataclass
class Demonstrations:
    """States with the oracle's choice: grids (N, n, n, n) uint8 (``LEVELS``), taken (N, V) bool,
    masks (N, V) bool (the views allowed), labels (N,) int64 (the oracle's view)."""

    grids: np.ndarray
    taken: np.ndarray
    masks: np.ndarray
    labels: np.ndarray

    def __len__(self) -> int:
        return len(self.labels)

    def __add__(self, other: "Demonstrations") -> "Demonstrations":
        return Demonstrations(*(np.concatenate([a, b]) for a, b in zip(self.arrays(), other.arrays())))

    def arrays(self) -> tuple[np.ndarray, ...]:
        return self.grids, self.taken, self.masks, self.labels

    def batch(self, rows: np.ndarray) -> tuple[torch.Tensor, ...]:
        """(grids float32 probabilities, taken float32, masks bool, labels int64) of ``rows``."""
        return (torch.from_numpy(self.grids[rows].astype(np.float32) / LEVELS),
                torch.from_numpy(self.taken[rows].astype(np.float32)),
                torch.from_numpy(self.masks[rows]), torch.from_numpy(self.labels[rows]))


def collect(env, choose: Choose, episodes: int, seed: int, expert_share: float = 1.0,
            stop: Callable[[], bool] | None = None) -> Demonstrations:
    """Run ``episodes`` episodes of ``env`` (a ``ReconstructEnv`` with ``info_scores=True``, or a
    wrapper of one) from ``reset(seed=seed)`` on, and keep every state decided at with the
    oracle's choice; each step the oracle acts with probability ``expert_share``, else
    ``choose(observation, mask)``. A state where no view adds anything (``nbv`` -1: only after a
    reset) has no label and is not kept. Seeded: the same arguments and policy give the same data.
    ``stop()`` true before an episode ends the collection there (a budget)."""
    if not 0.0 <= expert_share <= 1.0:
        raise ValueError(f"expert_share={expert_share!r}: must be in [0, 1]")
    rng = np.random.default_rng(seed)
    grids, taken, masks, labels = [], [], [], []
    for episode in range(episodes):
        if stop is not None and episode and stop():
            break
        observation, info = env.reset(seed=seed if episode == 0 else None)
        if "nbv" not in info:
            raise ValueError("collect needs the oracle's choice in info: make the environment with info_scores=True")
        done = False
        while not done:
            mask, label = np.asarray(info["action_mask"], dtype=bool), int(info["nbv"])
            expert = rng.random() < expert_share
            if label < 0:  # no view adds anything (a start that saw all it can): no label, any move
                action = int(np.flatnonzero(mask)[0]) if expert or choose is None else int(choose(observation, mask))
            else:
                grids.append(np.rint(observation["grid"] * LEVELS).astype(np.uint8))
                taken.append(observation["taken"] != 0)
                masks.append(mask)
                labels.append(label)
                action = label if expert else int(choose(observation, mask))
            observation, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
    views = env.action_space.n
    size = env.observation_space["grid"].shape
    return Demonstrations(np.stack(grids) if grids else np.zeros((0, *size), np.uint8),
                          np.stack(taken) if taken else np.zeros((0, views), bool),
                          np.stack(masks) if masks else np.zeros((0, views), bool),
                          np.asarray(labels, dtype=np.int64))


def masked_logits(logits: torch.Tensor, masks: torch.Tensor) -> torch.Tensor:
    """(B, V) logits with the views ``masks`` leaves out at -inf."""
    return logits.masked_fill(~masks, float("-inf"))


def clone(logits: Logits, parameters: Iterable[torch.nn.Parameter], data: Demonstrations, epochs: int,
          batch_size: int = 64, lr: float = 3e-4, seed: int = 0, stop: Callable[[], bool] | None = None) -> list[float]:
    """Fit ``logits`` to the oracle's choices in ``data`` (Adam, shuffled batches, seeded);
    returns the mean loss of every epoch begun. ``stop()`` true after a batch ends it there."""
    optimiser = torch.optim.Adam(list(parameters), lr=lr)
    rng = np.random.default_rng(seed)
    losses = []
    for _ in range(epochs):
        total, seen = 0.0, 0
        order = rng.permutation(len(data))
        for start in range(0, len(data), batch_size):
            if stop is not None and seen and stop():
                break
            grids, taken, masks, labels = data.batch(order[start:start + batch_size])
            loss = functional.cross_entropy(masked_logits(logits(grids, taken), masks), labels)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            total, seen = total + loss.item() * len(labels), seen + len(labels)
        losses.append(total / max(seen, 1))
        if stop is not None and stop():
            break
    return losses


@torch.no_grad()
def agreement(logits: Logits, data: Demonstrations, batch_size: int = 256) -> float:
    """Share of the states of ``data`` where the policy's most probable allowed view is the
    oracle's choice."""
    hits = 0
    for start in range(0, len(data), batch_size):
        grids, taken, masks, labels = data.batch(np.arange(start, min(start + batch_size, len(data))))
        hits += int((masked_logits(logits(grids, taken), masks).argmax(dim=1) == labels).sum())
    return hits / max(len(data), 1)


def greedy(logits: Logits) -> Choose:
    """The policy's most probable allowed view, as ``choose`` for ``collect``."""
    @torch.no_grad()
    def choose(observation: dict, mask: np.ndarray) -> int:
        grid = torch.from_numpy(np.asarray(observation["grid"], dtype=np.float32))[None]
        taken = torch.from_numpy(np.asarray(observation["taken"], dtype=np.float32))[None]
        return int(masked_logits(logits(grid, taken), torch.from_numpy(mask)[None]).argmax())
    return choose


def dagger(env, logits: Logits, parameters: list[torch.nn.Parameter], rounds: int, episodes: int, epochs: int,
           seed: int = 0, lr: float = 3e-4, batch_size: int = 64,
           after_round: Callable[[int, Demonstrations], None] | None = None,
           stop: Callable[[int], bool] | None = None) -> Demonstrations:
    """Round 0: ``episodes`` episodes of the oracle's, cloned for ``epochs``; rounds 1..rounds:
    ``episodes`` of the learner's own (its greedy choice), labelled by the oracle, added to the
    data, and all of it cloned again. ``after_round(round, data)`` is called after each;
    ``stop(round)`` true ends that round's collection, then its cloning, early (a budget).
    Returns the data of every round."""
    data = None
    for round_ in range(rounds + 1):
        share = 1.0 if round_ == 0 else 0.0
        halt = None if stop is None else (lambda r=round_: stop(r))
        new = collect(env, greedy(logits), episodes, seed + 1000 * round_, expert_share=share, stop=halt)
        data = new if data is None else data + new
        clone(logits, parameters, data, epochs, batch_size, lr, seed + round_, stop=halt)
        if after_round is not None:
            after_round(round_, data)
    return data
