"""NBV poses from a trained checkpoint: ``Predictor(checkpoint).predict(grid)``.

The network gives a position on the unit sphere's scale (regression: its tanh output,
classification: the chosen class view). The pose puts the sensor at that direction, scaled to
``radius * k`` metres (``radius``: the view sphere the network was trained on, 0.4 m by
default; ``k``: the paper's factor for a larger real scene, e.g. 2.5 for a 1 m sphere), looking
at the object centre with no rotation about the optical axis (image rows horizontal).

Angles are the authors' (x, y, z, yaw, pitch, roll) with R = Rz(yaw) Ry(pitch) Rx(roll)
world-to-camera, as in their dataset. In that convention the third row of R is the viewing
direction, so for a look-at pose "roll" is fixed by the direction; a spin about the optical
axis would show in yaw.
"""

from __future__ import annotations

import copy
import json
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from nbvdata.config import ConfigError
from nbvdata.views import Pose
from nbvtrain.checkpoint import load_checkpoint, model_from
from nbvtrain.models import GRID_SIZE, NBVNet, class_positions


@dataclass(frozen=True)
class NBVPrediction:
    """raw: (3,) the network's output; direction: (3,) unit; pose: the sensor pose."""

    raw: np.ndarray
    direction: np.ndarray
    pose: Pose

    def to_dict(self) -> dict:
        x, y, z, yaw, pitch, roll = self.pose.xyzypr.tolist()
        return {"position": [x, y, z], "yaw": yaw, "pitch": pitch, "roll": roll,
                "direction": self.direction.tolist(), "network_output": self.raw.tolist()}


class Predictor:
    """A checkpoint loaded for inference (eval mode, no gradients)."""

    def __init__(self, checkpoint: str | Path, device: str = "cpu", k: float = 1.0, radius: float | None = None):
        path = Path(checkpoint)
        state = load_checkpoint(path)
        self.model: NBVNet = model_from(state, path)
        try:
            self.device = torch.device(device)
            self.model.to(self.device).eval()
        except (RuntimeError, AssertionError) as error:  # an unknown device, or one this torch lacks
            raise ConfigError(f"device {device!r}: {str(error).strip()[:80]}: use cpu") from None
        self._features = _fast_features(self.model, self.device)
        self.name, self.epoch = state["model"], state["epoch"]
        self.radius = float(radius if radius is not None else state.get("view_radius", 0.4))
        self.k = float(k)
        self._classes = torch.from_numpy(class_positions()).float().to(self.device)

    def outputs(self, grids: np.ndarray) -> np.ndarray:
        """(B, n, n, n) or (n, n, n) probabilities -> (B, 3) network positions (unit-sphere scale).
        GridError (a ValueError) for anything else (see ``check_grids``)."""
        grids = check_grids(grids)
        with torch.inference_mode():
            output = self._features(torch.from_numpy(grids).to(self.device).unsqueeze(1))
            output = self.model.head(output)
            if self.model.task == "classification":
                output = self._classes[output.argmax(dim=1)]
        return output.cpu().numpy().astype(np.float64)

    def predict(self, grids: np.ndarray) -> list[NBVPrediction]:
        """(B, n, n, n) or (n, n, n) grids, authors' encoding (0.5 = unknown) -> B predictions.
        GridError (a ValueError) for anything else (see ``check_grids``)."""
        predictions = []
        for raw in self.outputs(grids):
            norm = np.linalg.norm(raw)
            direction = raw / norm if norm > 0 else np.array([0.0, 0.0, 1.0])
            pose = Pose.look_at(direction * self.radius * self.k)
            predictions.append(NBVPrediction(raw, direction, pose))
        return predictions


class GridError(ValueError):
    """Input that is not occupancy grids in the authors' encoding; the message says what is wrong."""


ENCODING = "float occupancy probabilities in [0, 1], 0.5 = unknown (the authors' encoding)"


def check_grids(grids: np.ndarray) -> np.ndarray:
    """(n, n, n) or (B, n, n, n) float probabilities in [0, 1], n = 32 -> (B, n, n, n) float32.

    GridError for another shape, an integer or boolean dtype, NaN or values outside [0, 1]."""
    array = np.asarray(grids)
    shape = (GRID_SIZE,) * 3
    if array.ndim not in (3, 4) or array.shape[-3:] != shape:
        raise GridError(f"grid has shape {array.shape}, expected {shape} or (B, {', '.join(map(str, shape))})")
    if array.dtype.kind != "f":
        raise GridError(f"grid has dtype {array.dtype}, expected {ENCODING}")
    if array.size:
        nan = np.isnan(array)
        if nan.any():
            raise GridError(f"grid holds {int(nan.sum())} NaN values of {array.size}: expected {ENCODING}")
        low, high = float(array.min()), float(array.max())
        if low < 0 or high > 1:
            raise GridError(f"grid holds values in [{low:g}, {high:g}], outside [0, 1]: expected {ENCODING}")
    array = array.astype(np.float32, copy=False)
    return array[None] if array.ndim == 3 else array


def _fast_features(model: NBVNet, device: torch.device) -> Callable[[torch.Tensor], torch.Tensor]:
    """The convolutional part for inference: on a CPU with oneDNN, the layers converted to
    oneDNN's blocked layout (2.3x faster at batch 1 here: 3.3 vs 7.7 ms for nbvnet-4-5, the
    same outputs to 1e-8; benchmarks/predict.py); elsewhere the model's own layers."""
    if device.type != "cpu" or not torch.backends.mkldnn.is_available():
        return model.features
    try:
        with warnings.catch_warnings():  # torch.utils.mkldnn builds on the deprecated torch.jit
            warnings.simplefilter("ignore", DeprecationWarning)
            from torch.utils import mkldnn

            features = mkldnn.to_mkldnn(copy.deepcopy(model.features))
    except (ImportError, AttributeError, RuntimeError):  # a torch without it: the plain layers
        return model.features
    return lambda grids: features(grids.to_mkldnn()).to_dense()


def prediction_json(prediction: NBVPrediction, predictor: Predictor, source: str) -> str:
    """The JSON ``nbvtrain predict`` prints."""
    return json.dumps({"source": source, "model": predictor.name, "epoch": predictor.epoch,
                       "radius": predictor.radius, "k": predictor.k, **prediction.to_dict()}, indent=2)
