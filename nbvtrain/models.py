"""The NBV-net family (regression, Vasquez-Gomez et al.) and the 14-view NBV-Net classifier.

Every model maps a batch of occupancy grids (B, 1, 32, 32, 32), float32 probabilities, to
(B, 3) unit-ish NBV positions (regression, tanh output) or (B, 14) logits (classification).

Convolutions are kernel 3, **stride 1, padding 1**, each followed by ReLU; a 2x max-pool follows
each of the first three (32 -> 16 -> 8 -> 4). The paper writes stride 2, but that cannot run on
a 32^3 input through three poolings and contradicts its own "4096 features" (= 64 x 4^3 for the
four-convolution nets); the authors' published classification code uses stride 1 with padding 1,
which is what is implemented here.

Dropout 0.5 is inserted "from layer N to the end" (the paper's wording): after the activation
of layer N and of every later hidden layer (never after the output). N is ``conv1`` ... ``conv4``,
``fc1`` ... (``fc`` = ``fc1``) or ``none``; the paper's best is ``conv3``.

Build models by name with ``build_model(name, dropout_from=...)``; ``MODELS`` lists them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

GRID_SIZE = 32


@dataclass(frozen=True)
class Architecture:
    """convs: filters per convolution; fcs: hidden fully connected widths; outputs: 3 or 14."""

    convs: tuple[int, ...]
    fcs: tuple[int, ...]
    outputs: int
    description: str

    @property
    def task(self) -> str:
        return "regression" if self.outputs == 3 else "classification"


MODELS: dict[str, Architecture] = {
    "nbvnet-3-3": Architecture((10, 12, 8), (1024, 500), 3, "C(10) P C(12) P C(8) P, FC(1024) FC(500) FC(3)"),
    "nbvnet-3-5": Architecture((10, 12, 8), (1500, 500, 100, 50), 3,
                               "C(10) P C(12) P C(8) P, FC(1500) FC(500) FC(100) FC(50) FC(3)"),
    "nbvnet-4-3": Architecture((16, 32, 64, 64), (1024, 500), 3,
                               "C(16) P C(32) P C(64) P C(64), FC(1024) FC(500) FC(3)"),
    "nbvnet-4-5": Architecture((16, 32, 64, 64), (1500, 500, 100, 50), 3,
                               "C(16) P C(32) P C(64) P C(64), FC(1500) FC(500) FC(100) FC(50) FC(3)"),
    # The earlier NBV-Net (Mendoza et al.): the 3-5 body with 14 class logits. Unlike its published
    # code: softmax is applied once (in the loss, or by the caller), PyTorch's default init runs.
    "nbvnet-class": Architecture((10, 12, 8), (1500, 500, 100, 50), 14,
                                 "C(10) P C(12) P C(8) P, FC(1500) FC(500) FC(100) FC(50) FC(14) logits"),
}
POOLED = 3  # the first three convolutions are followed by a 2x max-pool


def layer_names(name: str) -> list[str]:
    """The layers dropout can start from, in order: conv1..convK, fc1..fcM (hidden ones)."""
    arch = architecture(name)
    return [f"conv{i + 1}" for i in range(len(arch.convs))] + [f"fc{i + 1}" for i in range(len(arch.fcs))]


def architecture(name: str) -> Architecture:
    if name not in MODELS:
        raise ValueError(f"unknown model {name!r}: choose one of {', '.join(MODELS)}")
    return MODELS[name]


class NBVNet(nn.Module):
    """(B, 1, 32, 32, 32) grids -> (B, 3) tanh positions or (B, 14) logits."""

    def __init__(self, name: str, dropout_from: str = "conv3", dropout: float = 0.5):
        super().__init__()
        arch = architecture(name)
        names = layer_names(name)
        start = dropout_start_index(dropout_from, names)
        self.name, self.task = name, arch.task
        layers: list[nn.Module] = []
        channels = 1
        for i, filters in enumerate(arch.convs):
            layers += [nn.Conv3d(channels, filters, kernel_size=3, stride=1, padding=1), nn.ReLU(inplace=True)]
            if i < POOLED:
                layers.append(nn.MaxPool3d(2))
            if i >= start:
                layers.append(nn.Dropout(dropout))
            channels = filters
        self.features = nn.Sequential(*layers)
        side = GRID_SIZE // 2 ** min(POOLED, len(arch.convs))
        self.feature_count = channels * side ** 3
        layers, width = [nn.Flatten()], self.feature_count
        for i, units in enumerate(arch.fcs):
            layers += [nn.Linear(width, units), nn.ReLU(inplace=True)]
            if len(arch.convs) + i >= start:
                layers.append(nn.Dropout(dropout))
            width = units
        layers.append(nn.Linear(width, arch.outputs))
        if arch.task == "regression":
            layers.append(nn.Tanh())
        self.head = nn.Sequential(*layers)

    def forward(self, grids: torch.Tensor) -> torch.Tensor:
        return self.head(self.features(grids))


def dropout_start_index(dropout_from: str, names: list[str]) -> int:
    """Index into ``names`` of the first layer followed by dropout (len(names) for none)."""
    key = "fc1" if dropout_from == "fc" else dropout_from
    if key == "none":
        return len(names)
    if key not in names:
        raise ValueError(f"dropout_from={dropout_from!r}: choose one of none, {', '.join(names)}, fc")
    return names.index(key)


def build_model(name: str, dropout_from: str = "conv3", dropout: float = 0.5) -> NBVNet:
    """The registry's one factory."""
    return NBVNet(name, dropout_from, dropout)


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def class_positions(radius: float = 1.0) -> np.ndarray:
    """(14, 3) float64 positions of NBV-Net's 14 classes on a sphere of ``radius``.

    The first 14 of the authors' 20 golden-angle spiral points: height z = 0.95 - 0.1 k (on the
    0.4 m sphere 0.38, 0.34, ...) and azimuth -(k + 1/2) times the golden angle pi (3 - sqrt 5),
    k = 0..13; this reproduces their published points_in_sphere.txt to its 6 printed digits
    (tests/test_models.py).
    """
    k = np.arange(14)
    z = 0.95 - 0.1 * k
    azimuth = -(k + 0.5) * np.pi * (3.0 - np.sqrt(5.0))
    ring = np.sqrt(1.0 - z ** 2)
    return radius * np.stack([ring * np.cos(azimuth), ring * np.sin(azimuth), z], axis=1)
