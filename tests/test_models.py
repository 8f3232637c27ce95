"""The model registry: every network maps grids to the right shape, dropout sits where asked."""

import numpy as np
import pytest
import torch
from torch import nn

from nbvtrain.networks.models import MODELS, build_model, class_positions, layer_names, parameter_count

# The authors' points_in_sphere.txt (first, second and 14th rows), metres: published facts.
AUTHORS_CLASS_POINTS = {0: (0.045261, -0.116411, 0.38), 1: (-0.188964, 0.093234, 0.34),
                        13: (0.207602, -0.311932, -0.14)}


@pytest.mark.parametrize("name", [name for name, arch in MODELS.items() if arch.task != "scores"])
def test_every_model_maps_grids_to_its_output(name):  # score networks: tests/test_scores.py
    torch.manual_seed(0)
    model = build_model(name).eval()
    grids = torch.rand(3, 1, 32, 32, 32)
    with torch.no_grad():
        if MODELS[name].scans:  # where the sensor has been: (B, 42) closeness rows
            with pytest.raises(ValueError, match="scans=\\(B, 42\\)"):
                model(grids)
            output = model(grids, torch.rand(3, 42))
        else:
            output = model(grids)
    outputs = 3 if MODELS[name].task == "regression" else 14
    assert output.shape == (3, outputs) and torch.isfinite(output).all()
    if outputs == 3:
        assert output.abs().max() <= 1  # tanh
    convs = len(MODELS[name].convs)
    assert model.feature_count == (4096 if convs == 4 else 512)  # the paper's 4096 features
    print(f"{name}: {parameter_count(model):,} parameters")


def test_the_paper_sizes():
    assert parameter_count(build_model("nbvnet-4-5")) == 7_131_623  # REFERENCE.md: 7.1 M
    for conv in build_model("nbvnet-4-3").modules():
        if isinstance(conv, nn.Conv3d):
            assert conv.stride == (1, 1, 1) and conv.padding == (1, 1, 1) and conv.kernel_size == (3, 3, 3)


@pytest.mark.parametrize("name", ["nbvnet-3-5", "nbvnet-4-5", "nbvscore-fc3", "nbvscore-fc3-wide", "nbvscore-3",
                                  "nbvscore-pc"])
def test_dropout_from_layer_n_to_the_end(name):
    names = layer_names(name)
    views = np.eye(3) if MODELS[name].task == "scores" else None
    for start, layer in enumerate(names):
        model = build_model(name, dropout_from=layer, views=views)
        assert sum(isinstance(m, nn.Dropout) for m in model.modules()) == len(names) - start
    assert not any(isinstance(m, nn.Dropout) for m in build_model(name, "none", views=views).modules())
    assert sum(isinstance(m, nn.Dropout) for m in build_model(name, "fc", views=views).modules()) == \
        len([n for n in names if n.startswith("fc")])
    with pytest.raises(ValueError, match="dropout_from='conv9'"):
        build_model(name, dropout_from="conv9", views=views)


def test_unknown_model_names_the_choices():
    with pytest.raises(ValueError, match="nbvnet-4-5"):
        build_model("nbvnet-9")


def test_class_positions_are_the_authors_spiral_points():
    positions = class_positions(0.4)
    assert positions.shape == (14, 3)
    np.testing.assert_allclose(np.linalg.norm(positions, axis=1), 0.4)
    for row, point in AUTHORS_CLASS_POINTS.items():
        np.testing.assert_allclose(positions[row], point, atol=5e-7)
