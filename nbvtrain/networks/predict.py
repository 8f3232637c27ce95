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
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from nbvdata.core.cloud import reduce_cloud
from nbvdata.core.config import ConfigError
from nbvdata.core.userarrays import GridError, check_grids
from nbvdata.core.views import Pose
from nbvtrain.networks.checkpoint import load_checkpoint, model_from
from nbvtrain.networks.models import (GRID_SIZE, SCAN_DIRECTIONS, NBVNet, PointScoreNet, ScoreNet, class_positions,
                                      quarter_turns, scan_closeness, turn_closeness)
from nbvtrain.networks.scores import pick


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


TURNS = (0, 1, 2, 3)  # the quarter turns about z that test-time averaging (``tta``) adds up


class Predictor:
    """A checkpoint loaded for inference (eval mode, no gradients).

    ``tta``: quarter-turn test-time averaging, where it is exact: the grid is also turned by 1, 2
    and 3 quarter turns about z (``nbvtrain.networks.training_data.rotate_quarter_turns``), each turned grid is an
    exact sample of the same state turned, and the four answers are turned back and averaged: a
    regression network's positions turned back by the inverse turn, a score network that takes
    its views as inputs (``nbvscore-3``, ``ScoreNet.turns``) scoring each view at its turned
    direction (``ScoreNet.head``'s ``turns``). ConfigError for the others, whose outputs quarter
    turns do not map onto each other (the 14 class views, the output views of ``nbvscore-fc3``).
    """

    def __init__(self, checkpoint: str | Path, device: str = "cpu", k: float = 1.0, radius: float | None = None,
                 tta: bool = False):
        path = self.path = Path(checkpoint)
        state = load_checkpoint(path)
        self.model: NBVNet | ScoreNet | PointScoreNet = model_from(state, path)
        if tta and (self.model.task == "classification" or (self.model.task == "scores" and not getattr(self.model, "turns", False))):
            outputs = ("its 14 class views" if self.model.task == "classification" else
                       "its candidate views, which are outputs (nbvscore-3 takes them as inputs),")
            raise ConfigError(f"{path}: quarter-turn averaging (--tta) is not exact for {state['model']}: quarter "
                              f"turns do not map {outputs} onto each other; drop --tta for it")
        self.tta = bool(tta)
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
        if not (math.isfinite(self.k) and self.k > 0):
            raise ConfigError(f"k {self.k}: must be a positive finite number (--k)")
        if not (math.isfinite(self.radius) and self.radius > 0):
            where = "--radius" if radius is not None else f"the view_radius of {path}: pass --radius"
            raise ConfigError(f"view radius {self.radius}: must be a positive finite number of metres ({where})")

    def raw(self, grids: np.ndarray | list[np.ndarray], taken: np.ndarray | None = None,
            scans: np.ndarray | list[np.ndarray] | None = None) -> np.ndarray:
        """The network's own output for (B, n, n, n) or (n, n, n) probabilities: (B, 3) tanh
        positions, (B, 14) class logits or (B, V) candidate scores (``taken``: (V,) or (B, V) bool
        scanned views, default none); with ``tta`` the mean of the four quarter turns' outputs,
        turned back. GridError (a ValueError) for a bad grid (``check_grids``). A network that reads
        where the sensor has been (``nbvnet-4-3-scans``) takes ``scans``: the (S, 3) sensor positions
        scanned so far (object frame) for every grid, or a list of B of them; None: none yet.

        A point network (``inputs`` "points") takes clouds instead: one (M, 3) array or a list of
        B, object frame, metres, any M >= 1 - every point scanned, reduced here to the checkpoint's
        ``points`` as the generator reduces them (``nbvdata.core.cloud.reduce_cloud``)."""
        if self.inputs == "points":
            clouds = torch.from_numpy(self.clouds(grids)).to(self.device)
            with torch.inference_mode():
                state = torch.from_numpy(self.taken(taken, len(clouds))).to(self.device)
                return self.model(clouds, state).cpu().numpy().astype(np.float64)
        grids = check_grids(grids, GRID_SIZE)
        batch, turns = len(grids), TURNS if self.tta else (0,)
        if self.tta:  # (4B, n, n, n): the grids turned by 0..3 quarter turns, turn by turn
            grids = np.ascontiguousarray(np.concatenate([np.rot90(grids, turn, axes=(1, 2)) for turn in turns]))
        grids = torch.from_numpy(grids).to(self.device).unsqueeze(1)
        with torch.inference_mode():
            if self.model.task != "scores":
                closeness = self.closeness(scans, batch)
                if closeness is not None:  # (len(turns) B, K): the scans turned as their grids
                    closeness = torch.from_numpy(np.concatenate([turn_closeness(closeness, np.full(batch, turn))
                                                                 for turn in turns])).to(self.device)
                outputs = self.model.decide(self._features(grids), closeness).cpu().numpy().astype(np.float64)
                if not self.tta:
                    return outputs
                outputs = outputs.reshape(len(turns), batch, -1)  # regression: positions turned back
                return np.mean([quarter_turns(outputs[turn], -turn) for turn in turns], axis=0)
            state = torch.from_numpy(np.tile(self.taken(taken, batch), (len(turns), 1))).to(self.device)
            turned = torch.arange(len(turns), device=self.device).repeat_interleave(batch) if self.tta else None
            scores = self.model.head(self._features(self.model.encode(grids)), state, turned)
            return scores.cpu().numpy().astype(np.float64).reshape(len(turns), batch, -1).mean(axis=0)

    def clouds(self, clouds: np.ndarray | list[np.ndarray]) -> np.ndarray:
        """(B, points, 3) float32: each cloud (``check_cloud``) reduced to the checkpoint's size."""
        clouds = [clouds] if isinstance(clouds, np.ndarray) and np.ndim(clouds) == 2 else list(clouds)
        if not clouds:
            raise GridError(f"no point cloud given: {self.name} reads one (M, 3) cloud per state")
        return np.stack([reduce_cloud(check_cloud(cloud), self.points)[0] for cloud in clouds])

    def closeness(self, scans: np.ndarray | list[np.ndarray] | None, batch: int) -> np.ndarray | None:
        """(B, K) ``scan_closeness`` of ``scans`` (see ``raw``) for a network that reads them, else None."""
        if not getattr(self.model, "reads_scans", False):
            return None
        if scans is None:
            return np.zeros((batch, len(SCAN_DIRECTIONS)), dtype=np.float32)
        each = [scans] * batch if isinstance(scans, np.ndarray) and scans.ndim <= 2 else list(scans)
        if len(each) != batch or any(np.size(positions) and np.shape(positions)[-1] != 3 for positions in each):
            raise GridError(f"scans: give the (S, 3) sensor positions scanned so far, or a list of {batch} of them "
                            f"(one per grid), for {self.name}")
        return np.stack([scan_closeness(positions) for positions in each])

    def taken(self, taken: np.ndarray | None, batch: int) -> np.ndarray:
        """(B, V) bool view states of a score network from (V,), (B, V) or None (nothing scanned)."""
        views = len(self.view_units)
        state = np.zeros((batch, views), dtype=bool) if taken is None else np.asarray(taken, dtype=bool)
        state = np.broadcast_to(state, (batch, views)) if state.shape == (views,) else state
        if state.shape != (batch, views):
            raise GridError(f"view state has shape {np.shape(taken)}, expected ({views},) or ({batch}, {views}): one "
                            f"flag per candidate view of {self.name}")
        return np.array(state)  # a writable copy (torch.from_numpy wants one)

    def outputs(self, grids: np.ndarray, taken: np.ndarray | None = None,
                scans: np.ndarray | list[np.ndarray] | None = None) -> np.ndarray:
        """(B, n, n, n) or (n, n, n) probabilities (a point network: clouds, see ``raw``) -> (B, 3)
        network positions (unit-sphere scale):
        the regression output, the chosen class's view, or the unscanned candidate view (``taken``,
        see ``raw``) with the highest score. GridError (a ValueError) for a bad grid."""
        raw = self.raw(grids, taken, scans)
        if self.model.task == "classification":
            return class_positions()[raw.argmax(axis=1)]
        if self.model.task == "scores":
            return self.view_units[pick(raw, self.taken(taken, len(raw)))]
        return raw

    def predict(self, grids: np.ndarray, taken: np.ndarray | None = None,
                scans: np.ndarray | list[np.ndarray] | None = None) -> list[NBVPrediction]:
        """(B, n, n, n) or (n, n, n) grids, authors' encoding (0.5 = unknown; a point network: clouds,
        see ``raw``) -> B predictions
        (``taken``: a score network's scanned views, ``scans`` the scanned sensor positions, see
        ``raw``). GridError (a ValueError) for a bad grid (see ``check_grids``)."""
        predictions = []
        for raw in self.outputs(grids, taken, scans):
            norm = np.linalg.norm(raw)
            direction = raw / norm if norm > 0 else np.array([0.0, 0.0, 1.0])
            pose = Pose.look_at(direction * self.radius * self.k)
            predictions.append(NBVPrediction(raw, direction, pose))
        return predictions


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


def prediction_dict(prediction: NBVPrediction, predictor: Predictor, source: str,
                    taken: np.ndarray | None = None, scans: np.ndarray | None = None) -> dict:
    """The answer ``nbvtrain predict`` prints as JSON for one grid; for a score network also the
    chosen candidate ``view`` and the ``scanned`` views it was told of (``candidate_fields``); for
    a network that reads the sensor positions the (S, 3) ``scans`` it was given (``scanned_at``);
    ``tta``: true with quarter-turn averaging."""
    extra = candidate_fields(predictor.view_units, prediction.direction, taken)
    if scans is not None and getattr(predictor.model, "reads_scans", False):
        extra["scanned_at"] = np.asarray(scans, dtype=float).reshape(-1, 3).tolist()
    if predictor.tta:
        extra["tta"] = True
    return {"source": source, "checkpoint": str(predictor.path), "model": predictor.name, "epoch": predictor.epoch,
            "radius": predictor.radius, "k": predictor.k, **extra, **prediction.to_dict()}


def candidate_fields(view_units: np.ndarray | None, direction: np.ndarray, taken: np.ndarray | None) -> dict:
    """What a score network's answer adds to the JSON of ``predict`` and ``plan``: the chosen
    candidate ``view`` (the index of the candidate nearest to the (3,) ``direction``) and the
    ``scanned`` views it was told of (``taken``: (V,) bool, None = none); {} for a network without
    candidate views (``view_units`` None, else (V, 3) unit positions)."""
    if view_units is None:
        return {}
    return {"view": int(np.argmax(view_units @ direction)),
            "scanned": [] if taken is None else np.flatnonzero(taken).tolist()}
