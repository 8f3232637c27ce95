"""NBV poses from a trained checkpoint: ``Predictor(checkpoint).predict(grid)``.

The network gives a position on the unit sphere's scale (regression: its tanh output,
classification: the chosen class view, a score network: the unscanned candidate view with the
highest score, given which views were scanned - none unless told). The pose puts the sensor at that direction, scaled to
``radius * k`` metres (``radius``: the view sphere the network was trained on, 0.4 m by
default; ``k``: the paper's factor for a larger real scene, e.g. 2.5 for a 1 m sphere), looking
at the object centre with no rotation about the optical axis (image rows horizontal).

Angles are the authors' (x, y, z, yaw, pitch, roll) with R = Rz(yaw) Ry(pitch) Rx(roll)
world-to-camera, as in their dataset. In that convention the third row of R is the viewing
direction, so for a look-at pose "roll" is fixed by the direction; a spin about the optical
axis would show in yaw.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from nbvdata.cloud import reduce_cloud
from nbvdata.config import ConfigError
from nbvdata.views import Pose
from nbvtrain.checkpoint import load_checkpoint, model_from
from nbvtrain.models import GRID_SIZE, NBVNet, PointScoreNet, ScoreNet, class_positions
from nbvtrain.scores import pick


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
        path = self.path = Path(checkpoint)
        state = load_checkpoint(path)
        self.model: NBVNet | ScoreNet | PointScoreNet = model_from(state, path)
        try:
            self.device = torch.device(device)
            self.model.to(self.device).eval()
        except (RuntimeError, AssertionError) as error:  # an unknown device, or one this torch lacks
            raise ConfigError(f"device {device!r}: {str(error).strip()[:80]}: use cpu") from None
        self.inputs = self.model.inputs
        self._features = _fast_features(self.model, self.device) if self.inputs == "grid" else None
        self.name, self.epoch, self.scene = state["model"], state["epoch"], state.get("scene")
        self.points = int(state["points"]) if self.inputs == "points" else None  # model_from checked it
        self.view_units = state["view_units"].double().numpy() if self.model.task == "scores" else None
        self.radius = float(radius if radius is not None else state.get("view_radius", 0.4))
        self.k = float(k)

    def raw(self, grids: np.ndarray | list[np.ndarray], taken: np.ndarray | None = None) -> np.ndarray:
        """The network's own output for (B, n, n, n) or (n, n, n) probabilities: (B, 3) tanh
        positions, (B, 14) class logits or (B, V) candidate scores (``taken``: (V,) or (B, V) bool
        scanned views, default none). GridError (a ValueError) for a bad grid (``check_grids``).

        A point network (``inputs`` "points") takes clouds instead: one (M, 3) array or a list of
        B, object frame, metres, any M >= 1 - every point scanned, reduced here to the checkpoint's
        ``points`` as the generator reduces them (``nbvdata.cloud.reduce_cloud``)."""
        if self.inputs == "points":
            clouds = torch.from_numpy(self.clouds(grids)).to(self.device)
            with torch.inference_mode():
                state = torch.from_numpy(self.taken(taken, len(clouds))).to(self.device)
                return self.model(clouds, state).cpu().numpy().astype(np.float64)
        grids = torch.from_numpy(check_grids(grids)).to(self.device).unsqueeze(1)
        with torch.inference_mode():
            if self.model.task != "scores":
                return self.model.head(self._features(grids)).cpu().numpy().astype(np.float64)
            state = self.taken(taken, len(grids))
            features = self._features(self.model.encode(grids))
            return self.model.head(features, torch.from_numpy(state).to(self.device)).cpu().numpy().astype(np.float64)

    def clouds(self, clouds: np.ndarray | list[np.ndarray]) -> np.ndarray:
        """(B, points, 3) float32: each cloud (``check_cloud``) reduced to the checkpoint's size."""
        clouds = [clouds] if isinstance(clouds, np.ndarray) and np.ndim(clouds) == 2 else list(clouds)
        if not clouds:
            raise GridError(f"no point cloud given: {self.name} reads one (M, 3) cloud per state")
        return np.stack([reduce_cloud(check_cloud(cloud), self.points)[0] for cloud in clouds])

    def taken(self, taken: np.ndarray | None, batch: int) -> np.ndarray:
        """(B, V) bool view states of a score network from (V,), (B, V) or None (nothing scanned)."""
        views = len(self.view_units)
        state = np.zeros((batch, views), dtype=bool) if taken is None else np.asarray(taken, dtype=bool)
        state = np.broadcast_to(state, (batch, views)) if state.shape == (views,) else state
        if state.shape != (batch, views):
            raise GridError(f"view state has shape {np.shape(taken)}, expected ({views},) or ({batch}, {views}): one "
                            f"flag per candidate view of {self.name}")
        return np.array(state)  # a writable copy (torch.from_numpy wants one)

    def outputs(self, grids: np.ndarray, taken: np.ndarray | None = None) -> np.ndarray:
        """(B, n, n, n) or (n, n, n) probabilities (a point network: clouds, see ``raw``) -> (B, 3)
        network positions (unit-sphere scale):
        the regression output, the chosen class's view, or the unscanned candidate view (``taken``,
        see ``raw``) with the highest score. GridError (a ValueError) for a bad grid."""
        raw = self.raw(grids, taken)
        if self.model.task == "classification":
            return class_positions()[raw.argmax(axis=1)]
        if self.model.task == "scores":
            return self.view_units[pick(raw, self.taken(taken, len(raw)))]
        return raw

    def predict(self, grids: np.ndarray, taken: np.ndarray | None = None) -> list[NBVPrediction]:
        """(B, n, n, n) or (n, n, n) grids, authors' encoding (0.5 = unknown; a point network: clouds,
        see ``raw``) -> B predictions
        (``taken``: a score network's scanned views, see ``raw``). GridError (a ValueError) for a
        bad grid (see ``check_grids``)."""
        predictions = []
        for raw in self.outputs(grids, taken):
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


CLOUD = "(M, 3) finite float points, object frame, metres, M >= 1"


def check_cloud(cloud: np.ndarray) -> np.ndarray:
    """(M, 3) float32 of a cloud; GridError for another shape, a non-float dtype, no points or
    NaN/infinite coordinates."""
    array = np.asarray(cloud)
    if array.ndim != 2 or array.shape[1] != 3:
        raise GridError(f"cloud has shape {array.shape}, expected {CLOUD}")
    if array.dtype.kind != "f":
        raise GridError(f"cloud has dtype {array.dtype}, expected {CLOUD}")
    if not len(array):
        raise GridError(f"cloud holds no points: expected {CLOUD}")
    if not np.isfinite(array).all():
        raise GridError(f"cloud holds NaN or infinite coordinates: expected {CLOUD}")
    return array.astype(np.float32, copy=False)


def _fast_features(model: NBVNet | ScoreNet, device: torch.device) -> Callable[[torch.Tensor], torch.Tensor]:
    """The convolutional part for inference: on a CPU with oneDNN, the convolutions run on
    oneDNN's blocked layout (3x faster at batch 1 here: 2.5 vs 7.7 ms for nbvnet-4-5, the same
    outputs to 1e-7; benchmarks/predict.py); elsewhere the model's own layers.

    The convolutions call ``torch.mkldnn_convolution`` on pre-ordered weights directly, as
    ``torch.utils.mkldnn`` does inside ``torch.jit`` script modules (deprecated: they warn);
    pooling, ReLU and (eval-mode) dropout take oneDNN tensors as they are."""
    if device.type != "cpu" or not torch.backends.mkldnn.is_available():
        return model.features
    layers: list[Callable[[torch.Tensor], torch.Tensor]] = []
    reorder = getattr(torch._C._nn, "mkldnn_reorder_conv3d_weight", None)
    try:
        for layer in model.features:
            if isinstance(layer, torch.nn.Conv3d):
                weight, bias = layer.weight.detach().to_mkldnn(), layer.bias.detach().to_mkldnn()
                if reorder is not None:  # the weights in the layout the convolution wants, once
                    weight = reorder(weight, layer.padding, layer.stride, layer.dilation, layer.groups)
                layers.append(functools.partial(_mkldnn_conv, weight=weight, bias=bias, conv=layer))
            else:
                layers.append(layer)
        fast = functools.partial(_run_mkldnn, layers)
        with torch.inference_mode():
            channels = model.features[0].in_channels
            fast(torch.full((1, channels) + (GRID_SIZE,) * 3, 0.5))  # fails here where this torch cannot
    except (AttributeError, RuntimeError, TypeError):  # a torch without it: the plain layers
        return model.features
    return fast


def _mkldnn_conv(grids: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor,
                 conv: torch.nn.Conv3d) -> torch.Tensor:
    return torch.mkldnn_convolution(grids, weight, bias, conv.padding, conv.stride, conv.dilation, conv.groups)


def _run_mkldnn(layers: list[Callable[[torch.Tensor], torch.Tensor]], grids: torch.Tensor) -> torch.Tensor:
    grids = grids.to_mkldnn()
    for layer in layers:
        grids = layer(grids)
    return grids.to_dense()


def prediction_json(prediction: NBVPrediction, predictor: Predictor, source: str,
                    taken: np.ndarray | None = None) -> str:
    """The JSON ``nbvtrain predict`` prints; for a score network also the chosen candidate
    ``view`` and the ``scanned`` views it was told of."""
    extra = {}
    if predictor.view_units is not None:
        extra = {"view": int(np.argmax(predictor.view_units @ prediction.direction)),
                 "scanned": [] if taken is None else np.flatnonzero(taken).tolist()}
    return json.dumps({"source": source, "checkpoint": str(predictor.path), "model": predictor.name,
                       "epoch": predictor.epoch, "radius": predictor.radius, "k": predictor.k, **extra,
                       **prediction.to_dict()}, indent=2)
