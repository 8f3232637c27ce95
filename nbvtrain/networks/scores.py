"""Candidate-view scores: the losses a score network (``nbvscore-*``) learns from the full score
vectors, and how scores become a choice.

Every state of a shard carries the gain and overlap of every candidate view (``nbvdata.simulation.oracle``).
A view is *eligible* at a state when it passes the overlap rule (overlap >= ``oracle.min_overlap``)
and was not scanned yet; the label is the eligible view with the largest gain. The losses, each
over the eligible views of the states whose best eligible gain is > 0 (the others carry no
ranking and weigh 0):

- ``listwise``: cross-entropy between the softmax of the scores over the unscanned views and the
  target softmax((gain / best gain) / temperature) over the eligible views (ListNet, Cao et al.
  2007). Views that break the overlap rule get target 0, so the network learns the rule too.
- ``regression``: mean squared error between sigmoid(score) and gain / best gain over the
  unscanned views, 0 for views that break the overlap rule.
- ``argmax``: cross-entropy with the label alone (a 500-class classifier; the ablation's control
  for what the full vectors add).

A regression network (one position) can learn from the same vectors (``near_best_loss``): its
target is, of the *near-best* views (eligible, gain >= ``share`` x the best eligible gain), the one
nearest to its output, instead of the label alone. A state often has several views almost as good
as the best, far apart (train-meshes 1.2.0: at share 0.9 a median of 3, spread over 32 deg); the
label's squared error pulls the output to their mean, which may be no good view, while the nearest
one lets the network commit to any of them (a single-hypothesis "multiple choice" loss). With
share 1 it is the label's squared error (``nn.MSELoss``) whenever the best view is unique.

The choice of a score network is the unscanned view with the highest score (``pick``). Scores
of several sources (the networks of an ensemble, information gain) are combined after
``standardise``, which puts each on the same scale over the views that can be chosen.
"""

from __future__ import annotations

import numpy as np
import torch
from torch.nn import functional

SCORE_LOSSES = ("listwise", "regression", "argmax")


def targets(gains: torch.Tensor, valid: torch.Tensor, taken: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """((B, V) gain / best eligible gain, 0 where not eligible; (B,) bool state has a ranking).

    gains (B, V) float, valid (B, V) bool (overlap rule passed), taken (B, V) bool (scanned)."""
    eligible = valid & ~taken
    masked = torch.where(eligible, gains, torch.zeros_like(gains))
    best = masked.max(dim=1).values
    ranked = best > 0
    return masked / torch.where(ranked, best, torch.ones_like(best)).unsqueeze(1), ranked


def score_loss(scores: torch.Tensor, gains: torch.Tensor, valid: torch.Tensor, taken: torch.Tensor,
               kind: str = "listwise", temperature: float = 0.1) -> torch.Tensor:
    """The mean loss ``kind`` (see the module docstring) of (B, V) scores over the ranked states.

    gains (B, V), valid and taken (B, V) bool. 0 (with a gradient) when no state is ranked."""
    if kind not in SCORE_LOSSES:
        raise ValueError(f"score loss {kind!r}: choose one of {', '.join(SCORE_LOSSES)}")
    relative, ranked = targets(gains.float(), valid, taken)
    scores = scores.float()
    if not ranked.any():
        return scores.sum() * 0.0
    relative, scores, eligible = relative[ranked], scores[ranked], (valid & ~taken)[ranked]
    unscanned = ~taken[ranked]
    if kind == "regression":
        error = (torch.sigmoid(scores) - relative) ** 2
        return (error * unscanned).sum() / unscanned.sum()
    log_p = functional.log_softmax(scores.masked_fill(~unscanned, float("-inf")), dim=1)
    if kind == "argmax":
        return functional.nll_loss(log_p, relative.argmax(dim=1))
    target = functional.softmax((relative / temperature).masked_fill(~eligible, float("-inf")), dim=1)
    return -(target * log_p.masked_fill(~unscanned, 0.0)).sum(dim=1).mean()


def near_best_loss(output: torch.Tensor, labels: torch.Tensor, gains: torch.Tensor, valid: torch.Tensor,
                   taken: torch.Tensor, units: torch.Tensor, turns: torch.Tensor | None = None,
                   share: float = 0.9) -> torch.Tensor:
    """The mean over the batch of min over the near-best views of the squared error per coordinate
    (as ``nn.MSELoss``) between the (B, 3) ``output`` and a near-best view's unit position.

    labels (B, 3) the label positions (the target of a state with no ranking: its best gain is 0),
    gains (B, V), valid and taken (B, V) bool, units (V, 3) unit candidate positions, turns (B,)
    quarter turns about z the batch's grids and labels were turned by (the views turn alike:
    ``nbvtrain.networks.models.quarter_turns``), ``share`` in (0, 1]."""
    relative, ranked = targets(gains.float(), valid, taken)
    near = (relative >= share) & (valid & ~taken) & ranked.unsqueeze(1)
    back = output
    if turns is not None:  # the output turned back: distances to the views are those to the turned views
        cos = torch.tensor([1.0, 0.0, -1.0, 0.0], dtype=output.dtype, device=output.device)[turns]
        sin = torch.tensor([0.0, -1.0, 0.0, 1.0], dtype=output.dtype, device=output.device)[turns]
        x, y = output[:, 0], output[:, 1]
        back = torch.stack([cos * x - sin * y, sin * x + cos * y, output[:, 2]], dim=1)
    errors = ((back.unsqueeze(1) - units.to(output.dtype)) ** 2).mean(dim=2).masked_fill(~near, float("inf"))
    label_error = ((output - labels.to(output.dtype)) ** 2).mean(dim=1)
    return torch.where(ranked, errors.min(dim=1).values, label_error).mean()


def pick(scores: np.ndarray | torch.Tensor, taken: np.ndarray | torch.Tensor) -> np.ndarray:
    """(B,) the unscanned view with the highest score for (B, V) scores and (B, V) bool taken
    (ties: the lowest index; when every view was scanned, the highest-scoring one)."""
    scores = torch.as_tensor(scores).float()
    taken = torch.as_tensor(taken, dtype=torch.bool)
    full = taken.all(dim=1, keepdim=True)
    return scores.masked_fill(taken & ~full, float("-inf")).argmax(dim=1).cpu().numpy()


def standardise(scores: np.ndarray, free: np.ndarray) -> np.ndarray:
    """(V,) scores as z-scores over the ``free`` (V,) bool views (those that can be chosen; all
    views when none is free): minus their mean, over their standard deviation (kept unscaled
    when that is 0). An increasing affine map, so the order of the views - and ``pick`` - stays;
    invariant (up to rounding) to any positive scale and shift of ``scores``."""
    scores = np.asarray(scores, dtype=np.float64)
    free = np.asarray(free, dtype=bool)
    chosen = scores[free] if free.any() else scores
    spread = chosen.std()
    return (scores - chosen.mean()) / (spread if spread > 0 else 1.0)
