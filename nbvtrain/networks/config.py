"""Training settings: one frozen dataclass, loaded like the generator's (defaults, YAML, flags).

``configs/train.yaml`` lists every key with the paper's values; ``nbvtrain fit --config FILE``
reads one, command-line flags override it, and the resolved settings are saved as
``config.yaml`` in the run folder.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from nbvdata.core.config import ConfigError, require
from nbvtrain.networks.models import MODELS, dropout_start_index, layer_names


@dataclass(frozen=True)
class TrainConfig:
    model: str = "nbvnet-4-5"
    """Network from the registry: nbvnet-3-3, nbvnet-3-5, nbvnet-4-3, nbvnet-4-5, nbvnet-class, nbvscore-3."""
    dropout_from: str = "conv3"
    """First layer followed by dropout, to the end: conv1..conv4, fc (= fc1), fc2.., or none."""
    dropout: float = 0.5
    """Dropout probability (paper: 0.5)."""
    epochs: int = 600
    """Total epochs (paper: 600)."""
    batch_size: int = 250
    """Samples per step (paper: 250)."""
    lr: float = 1e-4
    """Adam learning rate (paper: 1e-4)."""
    lr_schedule: Literal["constant", "cosine"] = "constant"
    """constant (paper), or cosine: lr * (1 + cos(pi * (epoch - 1) / epochs)) / 2 in each epoch (a run
    resumed with more epochs follows the longer schedule from there)."""
    score_loss: Literal["listwise", "regression", "argmax"] = "listwise"
    """Score networks only: the loss over the full score vectors (``nbvtrain.networks.scores``)."""
    score_temperature: float = 0.1
    """Score networks, listwise loss: the target is softmax((gain / best gain) / temperature)."""
    regression_loss: Literal["label", "near-best"] = "label"
    """Regression networks only: label (paper: squared error to the labelled NBV), or near-best: to the
    nearest view whose gain is >= ``near_best`` x the best (``nbvtrain.networks.scores.near_best_loss``)."""
    near_best: float = 0.9
    """Regression, near-best loss: the share of the best eligible gain a view needs to be a target."""
    split: Literal["random", "mesh"] = "random"
    """random: a per-sample split (the paper's 80/20); mesh: whole objects held out."""
    val_fraction: float = 0.2
    """Share of samples (random) or of meshes (mesh) held out for validation."""
    augment: bool = False
    """Rotate each training grid and its target by a random multiple of 90 deg about z."""
    seed: int = 0
    """Seeds the split, the weights, the batch order, dropout and augmentation."""
    device: Literal["auto", "cpu", "cuda"] = "auto"
    """auto = cuda when available."""
    threads: int = 0
    """Torch CPU threads; 0 = torch's default (one per core)."""
    memory_limit_gb: float = 8.0
    """Load the grids into memory when they take at most this much, else read them lazily."""
    init: str | None = None
    """A checkpoint of ``nbvtrain fit`` (same ``model``) whose weights start the run instead of fresh
    ones: fine-tuning, e.g. on a DAgger round; the optimiser starts fresh. None: weights from ``seed``."""
    mixed_scenes: bool = False
    """Train on shards made in different scenes (settings that differ beyond ``episode``: views,
    sensor, grid, ...); refused by default. The checkpoint then records the scene as mixed, with
    every value its shards had (``nbvtrain.networks.trained_scene``)."""

    def __post_init__(self) -> None:
        require(self.model in MODELS, f"model={self.model!r}: choose one of {', '.join(MODELS)}")
        try:
            dropout_start_index(self.dropout_from, layer_names(self.model))
        except ValueError as error:
            raise ConfigError(str(error)) from None
        require(0 <= self.dropout < 1, f"dropout={self.dropout}: must lie in [0, 1)")
        require(self.epochs >= 1, f"epochs={self.epochs}: must be >= 1")
        require(self.batch_size >= 1, f"batch_size={self.batch_size}: must be >= 1")
        require(self.lr > 0, f"lr={self.lr}: must be > 0")
        require(self.score_temperature > 0, f"score_temperature={self.score_temperature}: must be > 0")
        require(0 < self.near_best <= 1, f"near_best={self.near_best}: must lie in (0, 1]")
        regression = [name for name, arch in MODELS.items() if arch.task == "regression"]
        require(self.regression_loss == "label" or self.model in regression,
               f"regression_loss={self.regression_loss} with {self.model}: a loss of the regression networks "
               f"({', '.join(regression)}); drop it")

        require(0 < self.val_fraction < 1, f"val_fraction={self.val_fraction}: must lie in (0, 1)")
        require(self.threads >= 0, f"threads={self.threads}: must be >= 0")
        require(self.memory_limit_gb >= 0, f"memory_limit_gb={self.memory_limit_gb}: must be >= 0")
