"""Candidate-score networks: the registry builds them, each loss prefers the known best view of a
tiny synthetic case (and respects the overlap rule and the scanned views), the choice never
repeats a scanned view, and scanned poses mark their candidate views."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nbvdata.core.views import scanned_views, sphere_positions
from nbvtrain.networks.config import TrainConfig
from nbvtrain.networks.models import MODELS, ScoreNet, build_model, parameter_count
from nbvtrain.networks.scores import SCORE_LOSSES, near_best_loss, pick, score_loss, targets


def test_the_registry_builds_the_score_family():  # the point network's: tests/test_pointnet.py
    names = [name for name, arch in MODELS.items() if arch.task == "scores"]
    assert names and all(name.startswith("nbvscore-") for name in names)
    for name in [name for name in names if MODELS[name].inputs == "grid"]:
        model = build_model(name, "fc1", 0.3, views=sphere_positions(37, 1.0, "hemisphere"))
        assert isinstance(model, ScoreNet) and model.task == "scores" and parameter_count(model) > 0
        scores = model.eval()(torch.full((5, 1, 32, 32, 32), 0.5), torch.zeros(5, 37, dtype=torch.bool))
        assert scores.shape == (5, 37) and torch.isfinite(scores).all()
        with pytest.raises(ValueError, match="views=\\(V, 3\\)"):
            build_model(name)
        assert TrainConfig(model=name, dropout_from="conv3").model == name


def test_the_wide_score_network_is_fc3_twice_as_wide():
    narrow, wide = MODELS["nbvscore-fc3"], MODELS["nbvscore-fc3-wide"]
    assert wide.convs == tuple(2 * c for c in narrow.convs) and wide.fcs == tuple(2 * f for f in narrow.fcs)
    units = sphere_positions(500, 1.0, "hemisphere")
    assert parameter_count(build_model("nbvscore-fc3", views=units)) == 2_942_916  # docs/score-networks.md
    assert parameter_count(build_model("nbvscore-fc3-wide", views=units)) == 10_742_164


def test_the_view_state_changes_the_scores():
    torch.manual_seed(0)
    model = build_model("nbvscore-3", "none", views=sphere_positions(10, 1.0, "hemisphere")).eval()
    grids = torch.rand(1, 1, 32, 32, 32)
    none, one = torch.zeros(1, 10, dtype=torch.bool), torch.zeros(1, 10, dtype=torch.bool)
    one[0, 3] = True
    assert not torch.allclose(model(grids, none), model(grids, one))


def _case():
    """4 views: view 1 gains most but breaks the overlap rule, view 3 was scanned (gain left
    high on purpose), view 2 is the best eligible one."""
    gains = torch.tensor([[0.2, 0.9, 0.5, 0.8]])
    valid = torch.tensor([[True, False, True, True]])
    taken = torch.tensor([[False, False, False, True]])
    return gains, valid, taken


@pytest.mark.parametrize("kind", SCORE_LOSSES)
def test_each_loss_prefers_the_best_eligible_view(kind):
    gains, valid, taken = _case()
    relative, ranked = targets(gains, valid, taken)
    assert ranked.tolist() == [True] and torch.allclose(relative, torch.tensor([[0.4, 0.0, 1.0, 0.0]]))
    losses = {}
    for view in range(4):
        scores = torch.full((1, 4), -3.0)
        scores[0, view] = 3.0
        losses[view] = score_loss(scores, gains, valid, taken, kind).item()
    assert min(losses, key=losses.get) == 2
    assert losses[2] < losses[1] and losses[2] < losses[0]
    # learning from zero scores ends at the best eligible view
    scores = torch.zeros(1, 4, requires_grad=True)
    optimizer = torch.optim.SGD([scores], lr=1.0)
    for _ in range(200):
        optimizer.zero_grad()
        score_loss(scores, gains, valid, taken, kind).backward()
        optimizer.step()
    assert pick(scores.detach(), taken).tolist() == [2]


def test_listwise_ranks_the_runner_up_above_the_rest():
    gains, valid, taken = _case()
    scores = torch.zeros(1, 4, requires_grad=True)
    optimizer = torch.optim.SGD([scores], lr=1.0)
    for _ in range(300):
        optimizer.zero_grad()
        score_loss(scores, gains, valid, taken, "listwise", temperature=0.5).backward()
        optimizer.step()
    assert scores[0, 2] > scores[0, 0] > scores[0, 1]


def test_states_without_a_gain_weigh_nothing():
    gains, valid, taken = torch.zeros(2, 4), torch.ones(2, 4, dtype=torch.bool), torch.zeros(2, 4, dtype=torch.bool)
    scores = torch.randn(2, 4, requires_grad=True)
    for kind in SCORE_LOSSES:
        loss = score_loss(scores, gains, valid, taken, kind)
        loss.backward()
        assert loss.item() == 0 and scores.grad.abs().sum() == 0
    with pytest.raises(ValueError, match="choose one of listwise"):
        score_loss(scores, gains, valid, taken, "hinge")


def test_the_choice_is_never_a_scanned_view(rng):
    scores = rng.normal(size=(200, 30))
    taken = rng.random((200, 30)) < 0.7
    taken[0] = True  # every view scanned: the best overall
    taken[1] = False
    chosen = pick(scores, taken)
    assert chosen[0] == np.argmax(scores[0]) and chosen[1] == np.argmax(scores[1])
    rows = np.arange(2, 200)
    assert not taken[rows, chosen[2:]].any()
    best = np.where(taken, -np.inf, scores).max(axis=1)
    assert np.array_equal(scores[rows, chosen[2:]], best[2:])


def test_scanned_poses_mark_their_candidate_views(rng):
    units = sphere_positions(500, 1.0, "hemisphere")
    chosen = rng.choice(500, 7, replace=False)
    taken = scanned_views(units[chosen] * 0.4, units)
    assert np.flatnonzero(taken).tolist() == sorted(chosen.tolist())
    nudged = scanned_views(units[chosen] * 0.4 + rng.normal(scale=1e-4, size=(7, 3)), units)
    assert np.array_equal(nudged, taken)
    assert not scanned_views(np.zeros((0, 3)), units).any()


def test_a_quarter_turn_of_the_grid_turns_each_views_side_alike(rng):
    """nbvscore-3 pools each view's side of the grid; for a grid turned as
    ``rotate_quarter_turns`` turns it, the turned views' sides are the original views' sides."""
    from nbvtrain.networks.models import quarter_turns
    from nbvtrain.networks.training_data import rotate_quarter_turns

    units = sphere_positions(50, 1.0, "hemisphere")
    model = build_model("nbvscore-3", "none", views=units)
    cells = rng.normal(size=(1, 8, 8, 8)).astype(np.float32)  # one feature channel on the 8^3 cells
    side = model.pooling[0].numpy() @ cells.reshape(512)
    for turns in (1, 2, 3):
        turned, directions = rotate_quarter_turns(cells, units[:1], np.array([turns]))
        np.testing.assert_allclose(directions, quarter_turns(units[:1], turns), atol=1e-12)
        np.testing.assert_allclose(model.pooling[turns].numpy() @ turned.reshape(512), side, rtol=1e-5, atol=1e-6)
        assert not np.allclose(model.pooling[0].numpy() @ turned.reshape(512), side, atol=1e-3)
    # the batch path groups samples by turn and gives each its own turn
    features = torch.from_numpy(rng.normal(size=(4, 32, 8, 8, 8)).astype(np.float32))
    taken = torch.zeros(4, 50, dtype=torch.bool)
    together = model.eval().head(features, taken, torch.tensor([0, 3, 1, 3]))
    alone = [model.head(features[i:i + 1], taken[:1], torch.tensor([t])) for i, t in enumerate((0, 3, 1, 3))]
    torch.testing.assert_close(together, torch.cat(alone))
    torch.testing.assert_close(model.head(features, taken, torch.zeros(4, dtype=torch.long)), model.head(features, taken))


def _near_case():
    """5 views on the axes: view 0 is the best eligible one (the label), view 2 gains 0.95 of it
    (near-best at share 0.9), view 1 gains more but breaks the overlap rule, view 3 was scanned,
    view 4 gains 0.5 of the best."""
    units = torch.tensor([[1.0, 0, 0], [0, 1.0, 0], [-1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0]])
    gains = torch.tensor([[1.0, 2.0, 0.95, 1.5, 0.5]])
    valid = torch.tensor([[True, False, True, True, True]])
    taken = torch.tensor([[False, False, False, True, False]])
    return units, units[:1], gains, valid, taken


def test_the_near_best_loss_takes_the_nearest_near_best_view():
    units, label, gains, valid, taken = _near_case()
    for output, target in (([0.9, 0.1, 0.0], 0), ([-0.8, 0.2, 0.1], 2), ([0.0, 1.0, 0.0], 0), ([0.0, -1.0, 0.0], 0),
                           ([0.1, 0.0, 0.9], 0)):  # views 1, 3 and 4 are never targets
        output = torch.tensor([output])
        expected = ((output - units[target]) ** 2).mean()
        torch.testing.assert_close(near_best_loss(output, label, gains, valid, taken, units, share=0.9), expected)
    # share 1: only the best view, the label's squared error (nn.MSELoss)
    output = torch.tensor([[-0.8, 0.2, 0.1]])
    torch.testing.assert_close(near_best_loss(output, label, gains, valid, taken, units, share=1.0),
                               torch.nn.MSELoss()(output, label))
    torch.testing.assert_close(near_best_loss(output, label, gains, valid, taken, units, share=0.4),
                               ((output - units[2]) ** 2).mean())  # view 4 is nearer, but not nearest


def test_the_near_best_loss_turns_its_views_with_the_grid(rng):
    from nbvtrain.networks.models import quarter_turns

    units = torch.from_numpy(sphere_positions(40, 1.0, "hemisphere")).float()
    gains = torch.from_numpy(rng.random((4, 40))).float()
    valid, taken = torch.ones(4, 40, dtype=torch.bool), torch.from_numpy(rng.random((4, 40)) < 0.2)
    output = torch.from_numpy(rng.normal(size=(4, 3)) * 0.5).float()
    labels = torch.zeros(4, 3)
    plain = [near_best_loss(output[i:i + 1], labels[i:i + 1], gains[i:i + 1], valid[i:i + 1], taken[i:i + 1], units,
                            share=0.8) for i in range(4)]
    turns = torch.tensor([0, 1, 2, 3])
    turned = torch.from_numpy(np.stack([quarter_turns(output[i:i + 1].double().numpy(), i)[0]
                                        for i in range(4)])).float()
    torch.testing.assert_close(near_best_loss(turned, labels, gains, valid, taken, units, turns, share=0.8),
                               torch.stack(plain).mean())
    # a turn changes the loss of an output left unturned
    assert not torch.isclose(near_best_loss(output, labels, gains, valid, taken, units, turns, share=0.8),
                             torch.stack(plain).mean())


def test_a_state_without_a_gain_learns_the_label_with_finite_gradients():
    units, label, gains, valid, taken = _near_case()
    gains = torch.cat([gains, torch.zeros(1, 5)])
    valid, taken, labels = valid.repeat(2, 1), taken.repeat(2, 1), torch.tensor([[1.0, 0, 0], [0, 0, 1.0]])
    output = torch.tensor([[0.5, 0.5, 0.0], [0.0, 0.5, 0.5]], requires_grad=True)
    loss = near_best_loss(output, labels, gains, valid, taken, units, share=0.9)
    loss.backward()
    expected = (((output[0] - units[0]) ** 2).mean() + ((output[1] - labels[1]) ** 2).mean()) / 2
    torch.testing.assert_close(loss, expected)
    assert torch.isfinite(output.grad).all() and (output.grad[1] != 0).any()
