"""nbvtrain.networks.metrics: the paper's errors and a gain ratio that follows the overlap rule the labels
were made with, on hand-made arrays and on generated smoke shards."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nbvdata.cli import main as nbvdata_main
from nbvdata.schema.shards import shard_files
from nbvtrain.networks.metrics import evaluate, gain_ratio
from nbvtrain.networks.training_data import load_shards

ROOT = Path(__file__).resolve().parents[1]
VIEWS = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, 1.0, 0]])


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    out = tmp_path_factory.mktemp("smoke") / "shards"
    assert nbvdata_main(["generate", "--config", str(ROOT / "configs" / "smoke.yaml"), "--out", str(out),
                         "--no-progress"]) == 0
    shards = load_shards(shard_files([out]))
    yield shards
    shards.close()


def test_metrics_on_known_predictions():
    gains = np.array([[0.1, 0.4, 0.2], [0.3, 0.0, 0.6]], dtype=np.float32)
    valid = np.array([[True, False, True], [True, True, True]])  # state 0: view 1 gains most but is invalid
    targets = VIEWS[[2, 2]]  # the labels: the best valid views
    perfect = evaluate(targets, targets, gains, VIEWS, valid)
    assert perfect == {"mse": 0.0, "mae": 0.0, "angle_deg": 0.0, "gain_ratio": 1.0, "invalid_share": 0.0}
    wrong = evaluate(-targets, targets, gains, VIEWS, valid)
    assert wrong["angle_deg"] == pytest.approx(180) and wrong["mse"] == pytest.approx(4 / 3)
    # nearest to view 0 in both states: 0.1 / 0.2 and 0.3 / 0.6
    near_0 = np.array([[0, 0.1, 1.0], [0.1, 0, 1.0]])
    assert evaluate(near_0, targets, gains, VIEWS, valid)["gain_ratio"] == pytest.approx((0.5 + 0.5) / 2)
    # ignoring the overlap rule: the invalid view 1 in state 0 counts 0, not 0.4 / 0.4
    greedy = VIEWS[[1, 2]]
    ratios, invalid = gain_ratio(greedy, gains, valid, VIEWS)
    assert ratios.tolist() == [0.0, 1.0] and invalid.tolist() == [True, False]
    assert evaluate(greedy, targets, gains, VIEWS, valid)["invalid_share"] == 0.5
    assert np.isnan(evaluate(targets, targets)["gain_ratio"]) and np.isnan(evaluate(targets, targets)["invalid_share"])
    with pytest.raises(ValueError, match=r"gains \(2, 3\) and valid \(2, 2\)"):
        gain_ratio(targets, gains, valid[:, :2], VIEWS)


def test_the_exact_labels_score_exactly_one_on_generated_shards(data):
    assert data.valid is not None and data.valid.shape == data.gains.shape
    perfect = evaluate(data.targets, data.targets, data.gains, data.view_units, data.valid)
    assert perfect["gain_ratio"] == 1.0 and perfect["invalid_share"] == 0.0
    # the labels are valid views: overlap >= the shards' oracle.min_overlap (0.2)
    labels = np.argmax(data.targets @ data.view_units.T, axis=1)
    assert data.valid[np.arange(len(data)), labels].all()


def test_ignoring_the_overlap_rule_never_beats_the_labels(data):
    """Predicting the most informative view, valid or not, scored 1 (above the labels) with the
    old ratio; now it scores 0 wherever that view is invalid."""
    greedy = data.view_units[np.argmax(data.gains, axis=1)]
    beats = data.gains.max(axis=1) > np.where(data.valid, data.gains, 0).max(axis=1)
    assert 0 < beats.mean() < 1  # smoke shards have such states (half of them)
    scores = evaluate(greedy, data.targets, data.gains, data.view_units, data.valid)
    assert scores["invalid_share"] == pytest.approx(beats.mean())
    assert scores["gain_ratio"] == pytest.approx(1 - beats.mean())  # 1 where valid (it is the label), else 0
