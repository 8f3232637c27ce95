"""The NBV-net family (regression, Vasquez-Gomez et al.), the 14-view NBV-Net classifier, and
the candidate-score family ``nbvscore-*``.

The NBV-nets map a batch of occupancy grids (B, 1, 32, 32, 32), float32 probabilities, to
(B, 3) unit-ish NBV positions (regression, tanh output) or (B, 14) logits (classification).
``nbvnet-4-3-scans`` also reads where the sensor has been: (B, K) ``scan_closeness`` of the
scanned sensor positions to K = 42 fixed directions, joined to the first FC layer's input.
A score network maps grids and the view state (B, V) bool (which of the V candidate views
were scanned) to (B, V) scores, one per candidate view (task ``scores``; ``ScoreNet``).
``nbvscore-pc`` does the same from the state's partial point cloud (B, N, 3) instead of the grid
(``PointScoreNet``, after PC-NBV; its ``inputs`` are "points").

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

from nbvdata.core.views import nearest_scan_cosines

GRID_SIZE = 32


@dataclass(frozen=True)
class Architecture:
    """convs: filters per convolution (for a point network: widths of the MLP shared by every
    point); fcs: hidden fully connected widths; outputs: 3, 14, or 0 = one per candidate view (a
    score network, whose convolutions have stride 2, no pooling); inputs: "grid" (B, 1, 32, 32,
    32) probabilities or "points" (B, N, 3) partial clouds in the object frame, metres; scans:
    also reads (B, K) ``scan_closeness`` (a regression network); widens: the network whose weights
    it starts from exactly (``fit --init``), the new inputs' weights zero."""

    convs: tuple[int, ...]
    fcs: tuple[int, ...]
    outputs: int
    description: str
    inputs: str = "grid"
    scans: bool = False
    widens: str = ""

    @property
    def task(self) -> str:
        return {3: "regression", 0: "scores"}.get(self.outputs, "classification")


MODELS: dict[str, Architecture] = {
    "nbvnet-3-3": Architecture((10, 12, 8), (1024, 500), 3, "C(10) P C(12) P C(8) P, FC(1024) FC(500) FC(3)"),
    "nbvnet-3-5": Architecture((10, 12, 8), (1500, 500, 100, 50), 3,
                               "C(10) P C(12) P C(8) P, FC(1500) FC(500) FC(100) FC(50) FC(3)"),
    "nbvnet-4-3": Architecture((16, 32, 64, 64), (1024, 500), 3,
                               "C(16) P C(32) P C(64) P C(64), FC(1024) FC(500) FC(3)"),
    # nbvnet-4-3 told where the sensor has been (issue 27's "regression network given the view
    # state"): fc1 also reads the scans' closeness to 42 fixed directions; from nbvnet-4-3's
    # weights with zeros for those columns it starts as that network.
    "nbvnet-4-3-scans": Architecture((16, 32, 64, 64), (1024, 500), 3,
                                     "C(16) P C(32) P C(64) P C(64), [., scan closeness (42)] FC(1024) FC(500) FC(3)",
                                     scans=True, widens="nbvnet-4-3"),
    "nbvnet-4-5": Architecture((16, 32, 64, 64), (1500, 500, 100, 50), 3,
                               "C(16) P C(32) P C(64) P C(64), FC(1500) FC(500) FC(100) FC(50) FC(3)"),
    # The earlier NBV-Net (Mendoza et al.): the 3-5 body with 14 class logits. Unlike its published
    # code: softmax is applied once (in the loss, or by the caller), PyTorch's default init runs.
    "nbvnet-class": Architecture((10, 12, 8), (1500, 500, 100, 50), 14,
                                 "C(10) P C(12) P C(8) P, FC(1500) FC(500) FC(100) FC(50) FC(14) logits"),
    # Candidate scores (after PC-NBV's per-view scores and SCVP's view-state input); both take 2
    # input channels (probability, unknown) through stride-2 convolutions instead of
    # full-resolution ones and pooling (8x fewer operations in the first layer).
    # nbvscore-3: one shared head scores each view from what lies on its side of the grid
    # (ViewScoreNet); C(32) keeps the 8^3 cells.
    "nbvscore-3": Architecture((16, 32, 32), (64, 64), 0,
                               "C(16)/2 C(32)/2 C(32), per view: [side pooling, FC(64) of global pooling, "
                               "direction, view state] FC(64) FC(64) FC(1)"),
    # nbvscore-fc3: a fully connected head with one output per view (FC(V)), the view state
    # joined as V inputs (the ablation's first design: it learns each view apart).
    "nbvscore-fc3": Architecture((16, 32, 64), (512, 512), 0,
                                 "C(16)/2 C(32)/2 C(64)/2, FC(512), [., view state] FC(512) FC(V) scores"),
    # nbvscore-fc3-wide: the same design twice as wide (3.6x the parameters, 10.7 M; 2.9x the time
    # a batch on a CPU), issue 27's "larger nbvscore-fc3 with more data".
    "nbvscore-fc3-wide": Architecture((32, 64, 128), (1024, 1024), 0,
                                      "C(32)/2 C(64)/2 C(128)/2, FC(1024), [., view state] FC(1024) FC(V) scores"),
    # nbvscore-pc: PC-NBV's kind of input, the partial cloud: a PointNet encoder (an MLP shared by
    # every point, max-pooled over the points) joined with the view state, one output per view.
    "nbvscore-pc": Architecture((64, 128, 256), (512, 256), 0,
                                "per point MLP(64, 128, 256), max pool; [., view state] FC(512) FC(256) FC(V) scores",
                                inputs="points"),
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
    """(B, 1, 32, 32, 32) grids -> (B, 3) tanh positions or (B, 14) logits; a network that
    ``reads_scans`` also takes (B, K) ``scan_closeness`` rows (``forward(grids, scans)``)."""

    inputs = "grid"

    def __init__(self, name: str, dropout_from: str = "conv3", dropout: float = 0.5):
        super().__init__()
        arch = architecture(name)
        names = layer_names(name)
        start = dropout_start_index(dropout_from, names)
        self.name, self.task, self.reads_scans = name, arch.task, arch.scans
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
        layers, width = [nn.Flatten()], self.feature_count + (len(SCAN_DIRECTIONS) if arch.scans else 0)
        for i, units in enumerate(arch.fcs):
            layers += [nn.Linear(width, units), nn.ReLU(inplace=True)]
            if len(arch.convs) + i >= start:
                layers.append(nn.Dropout(dropout))
            width = units
        layers.append(nn.Linear(width, arch.outputs))
        if arch.task == "regression":
            layers.append(nn.Tanh())
        self.head = nn.Sequential(*layers)

    def forward(self, grids: torch.Tensor, scans: torch.Tensor | None = None) -> torch.Tensor:
        return self.decide(self.features(grids), scans)

    def decide(self, features: torch.Tensor, scans: torch.Tensor | None = None) -> torch.Tensor:
        """The head on (B, C, s, s, s) features, joined with (B, K) ``scans`` when it reads them."""
        if not self.reads_scans:
            return self.head(features)
        if scans is None or scans.shape != (len(features), len(SCAN_DIRECTIONS)):
            raise ValueError(f"{self.name} reads where the sensor has been: give scans=(B, {len(SCAN_DIRECTIONS)}) "
                             "scan_closeness rows")
        return self.head[1:](torch.cat([self.head[0](features), scans.to(features.dtype)], dim=1))


def dropout_start_index(dropout_from: str, names: list[str]) -> int:
    """Index into ``names`` of the first layer followed by dropout (len(names) for none)."""
    key = "fc1" if dropout_from == "fc" else dropout_from
    if key == "none":
        return len(names)
    if key not in names:
        raise ValueError(f"dropout_from={dropout_from!r}: choose one of none, {', '.join(names)}, fc")
    return names.index(key)


def _score_convolutions(arch: Architecture, strides: tuple[int, ...], start: int, dropout: float) -> nn.Sequential:
    layers: list[nn.Module] = []
    channels = 2
    for i, (filters, stride) in enumerate(zip(arch.convs, strides)):
        layers += [nn.Conv3d(channels, filters, kernel_size=3, stride=stride, padding=1), nn.ReLU(inplace=True)]
        if i >= start:
            layers.append(nn.Dropout(dropout))
        channels = filters
    return nn.Sequential(*layers)


def _dropout(index: int, start: int, dropout: float) -> list[nn.Module]:
    return [nn.Dropout(dropout)] if index >= start else []


class ScoreNet(nn.Module):
    """(B, 1, 32, 32, 32) grids and (B, V) bool view states -> (B, V) candidate-view scores
    (``nbvscore-fc3``: a fully connected head with one output per candidate view).

    ``encode`` turns probabilities into the two input channels (p, p == 0.5); ``features`` are
    the convolutions; ``head(features, taken)`` gives the scores. A higher score means a better
    next view; scanned views are not masked here (the planner and the loss do that).
    """

    turns = False  # its views are outputs, not inputs: the quarter-turn augmentation cannot apply
    inputs = "grid"

    def __init__(self, name: str, units: np.ndarray, dropout_from: str = "fc1", dropout: float = 0.5):
        super().__init__()
        arch = architecture(name)
        start = dropout_start_index(dropout_from, layer_names(name))
        self.name, self.task, self.views = name, arch.task, len(units)
        self.features = _score_convolutions(arch, (2,) * len(arch.convs), start, dropout)
        side = GRID_SIZE // 2 ** len(arch.convs)
        first, joint = arch.fcs
        self.grid_head = nn.Sequential(nn.Flatten(), nn.Linear(arch.convs[-1] * side ** 3, first),
                                       nn.ReLU(inplace=True), *_dropout(len(arch.convs), start, dropout))
        self.joint_head = nn.Sequential(nn.Linear(first + self.views, joint), nn.ReLU(inplace=True),
                                        *_dropout(len(arch.convs) + 1, start, dropout), nn.Linear(joint, self.views))

    @staticmethod
    def encode(grids: torch.Tensor) -> torch.Tensor:
        """(B, 1, n, n, n) probabilities -> (B, 2, n, n, n): the probability and an unknown mask."""
        return torch.cat([grids, (grids == 0.5).to(grids.dtype)], dim=1)

    def head(self, features: torch.Tensor, taken: torch.Tensor, turns: torch.Tensor | None = None) -> torch.Tensor:
        """(B, C, s, s, s) features and (B, V) view states -> (B, V) scores."""
        return self.joint_head(torch.cat([self.grid_head(features), taken.to(features.dtype)], dim=1))

    def forward(self, grids: torch.Tensor, taken: torch.Tensor, turns: torch.Tensor | None = None) -> torch.Tensor:
        return self.head(self.features(self.encode(grids)), taken, turns)


class ViewScoreNet(ScoreNet):
    """``nbvscore-3``: every candidate view is scored by one shared head from

    - its side of the grid: the 8^3 feature cells averaged with weights max(0, cos)^2 of the
      angle between the cell's direction from the centre and the view's direction,
    - the whole grid: FC of the mean and max of the cells,
    - its direction (unit vector, object frame),
    - the view state near it: whether it was scanned, and the scanned views summed with weights
      exp((cos - 1) / 0.02) and exp((cos - 1) / 0.2) of their angle to it (close, and nearby).

    Views are inputs (their directions), so a grid turned by a quarter turn about z with its
    view directions turned alike is an exact new sample (``turns``: (B,) 0..3 per sample, as
    ``nbvtrain.networks.training_data.rotate_quarter_turns`` turns the grids).
    """

    turns = True
    CLOSE, NEARBY = 0.02, 0.2

    def __init__(self, name: str, units: np.ndarray, dropout_from: str = "fc1", dropout: float = 0.5):
        nn.Module.__init__(self)
        arch = architecture(name)
        start = dropout_start_index(dropout_from, layer_names(name))
        self.name, self.task, self.views = name, arch.task, len(units)
        strides = (2, 2) + (1,) * (len(arch.convs) - 2)
        self.features = _score_convolutions(arch, strides, start, dropout)
        side, channels = GRID_SIZE // 4, arch.convs[-1]
        centres = (np.arange(side) - (side - 1) / 2) / (side / 2)
        cells = np.stack(np.meshgrid(centres, centres, centres, indexing="ij"), axis=-1).reshape(-1, 3)
        units = np.asarray(units, dtype=np.float64)
        cosine = np.clip(units @ units.T, -1.0, 1.0)
        cells /= np.linalg.norm(cells, axis=1, keepdims=True)
        self.register_buffer("units", torch.from_numpy(units).float(), persistent=False)
        pooling = []  # (4, V, cells): each quarter turn's side weights, rows summing to 1
        for turn in range(4):
            weights = np.maximum(quarter_turns(units, turn) @ cells.T, 0.0) ** 2
            pooling.append(weights / weights.sum(axis=1, keepdims=True))
        self.register_buffer("pooling", torch.from_numpy(np.stack(pooling)).float(), persistent=False)
        self.register_buffer("closeness", torch.from_numpy(np.stack([np.exp((cosine - 1) / self.CLOSE),
                                                                     np.exp((cosine - 1) / self.NEARBY)])).float(),
                             persistent=False)
        width, hidden = arch.fcs
        conv_count = len(arch.convs)
        self.global_head = nn.Sequential(nn.Linear(2 * channels, width), nn.ReLU(inplace=True),
                                         *_dropout(conv_count, start, dropout))
        self.view_head = nn.Sequential(nn.Linear(channels + width + 3 + 3, hidden), nn.ReLU(inplace=True),
                                       *_dropout(conv_count + 1, start, dropout), nn.Linear(hidden, hidden),
                                       nn.ReLU(inplace=True), nn.Linear(hidden, 1))

    def head(self, features: torch.Tensor, taken: torch.Tensor, turns: torch.Tensor | None = None) -> torch.Tensor:
        """(B, C, 8, 8, 8) features, (B, V) view states, (B,) quarter turns -> (B, V) scores."""
        batch = len(features)
        cells = features.flatten(2).transpose(1, 2)  # (B, 512, C)
        whole = self.global_head(torch.cat([cells.mean(dim=1), cells.amax(dim=1)], dim=1))  # (B, W)
        if turns is None:
            side, units = self.pooling[0] @ cells, self.units.expand(batch, -1, -1)  # (B, V, C), (B, V, 3)
        else:
            side = cells.new_empty(batch, self.views, cells.shape[2])
            for turn in range(4):  # grouped by turn: no (B, V, 512) gather of the weights
                mine = turns == turn
                if mine.any():
                    side[mine] = self.pooling[turn] @ cells[mine]
            angle = turns.to(cells.dtype)[:, None] * (np.pi / 2)
            c, s = torch.round(torch.cos(angle)), torch.round(torch.sin(angle))
            x, y = self.units[:, 0], self.units[:, 1]
            units = torch.stack([c * x - s * y, s * x + c * y, self.units[:, 2].expand(batch, -1)], dim=-1)
        scanned = taken.to(cells.dtype)
        near = torch.stack([scanned, scanned @ self.closeness[0].T, scanned @ self.closeness[1].T], dim=-1)
        views = torch.cat([side, whole[:, None].expand(-1, self.views, -1), units, near], dim=-1)
        return self.view_head(views).squeeze(-1)


def quarter_turns(vectors: np.ndarray, turns: int) -> np.ndarray:
    """(N, 3) vectors turned by ``turns`` quarter turns about z, (x, y) -> (-y, x) each: the turn
    ``nbvtrain.networks.training_data.rotate_quarter_turns`` applies to grids and targets."""
    c, s = round(np.cos(turns * np.pi / 2)), round(np.sin(turns * np.pi / 2))
    x, y = vectors[:, 0], vectors[:, 1]
    return np.stack([c * x - s * y, s * x + c * y, vectors[:, 2]], axis=1)


def _scan_directions() -> np.ndarray:
    """(42, 3) float64 unit directions: 8 azimuths (every 45 degrees) at elevations -60, -30, 0,
    30 and 60 degrees, then the two poles; a quarter turn about z permutes them exactly."""
    elevation, azimuth = np.meshgrid(np.radians([-60.0, -30.0, 0.0, 30.0, 60.0]), np.arange(8) * (np.pi / 4),
                                     indexing="ij")
    rings = np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                      np.sin(elevation)], axis=-1).reshape(-1, 3)
    return np.concatenate([rings, [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]])


SCAN_DIRECTIONS = _scan_directions()
SCAN_WIDTH = 0.1  # closeness exp((cos - 1) / width): 0.26 at 30 degrees, 0.05 at 45
# (4, K): SCAN_TURNS[t][k] is the direction that t quarter turns take onto direction k, so the
# closeness of scans turned by t quarter turns is ``closeness[..., SCAN_TURNS[t]]`` (``turn_closeness``)
SCAN_TURNS = np.stack([np.argmax(quarter_turns(SCAN_DIRECTIONS, -t) @ SCAN_DIRECTIONS.T, axis=1) for t in range(4)])


def scan_closeness(positions: np.ndarray) -> np.ndarray:
    """(K,) float32: for each of the K ``SCAN_DIRECTIONS``, exp((cos - 1) / ``SCAN_WIDTH``) of its
    angle to the nearest of the scanned sensor positions (S, 3) (object frame, any radius;
    ``nbvdata.core.views.nearest_scan_cosines``); zeros when S = 0."""
    with np.errstate(invalid="ignore"):  # S = 0: exp(-inf) = 0
        return np.exp((nearest_scan_cosines(SCAN_DIRECTIONS, positions) - 1.0) / SCAN_WIDTH).astype(np.float32)


def view_state_closeness(taken: np.ndarray, view_units: np.ndarray) -> np.ndarray:
    """(N, K) float32 ``scan_closeness`` of every view state's scanned views: ``taken`` (N, V) bool,
    ``view_units`` (V, 3) their unit directions; the same numbers as ``scan_closeness`` of the
    scanned views' directions, row by row."""
    per_view = np.stack([scan_closeness(unit) for unit in np.asarray(view_units, dtype=np.float64)])  # (V, K)
    out = np.zeros((len(taken), len(SCAN_DIRECTIONS)), dtype=np.float32)
    for start in range(0, len(taken), 1024):
        rows = np.asarray(taken[start:start + 1024], dtype=bool)
        out[start:start + 1024] = np.where(rows[:, :, None], per_view[None], 0.0).max(axis=1)
    return out


def turn_closeness(closeness: np.ndarray, turns: np.ndarray) -> np.ndarray:
    """(B, K) ``scan_closeness`` rows of scans turned by ``turns`` (B,) quarter turns about z
    (``quarter_turns``): a permutation of each row, exact."""
    return np.take_along_axis(np.asarray(closeness), SCAN_TURNS[np.asarray(turns) % 4], axis=1)


class PointScoreNet(nn.Module):
    """``nbvscore-pc``: (B, N, 3) partial clouds (object frame, metres) and (B, V) view states ->
    (B, V) candidate-view scores.

    The points are scaled by ``point_scale`` (a saved buffer: 1 / the training views' radius,
    set by ``nbvtrain fit``; 1 until then), each goes through the same MLP (``convs`` widths,
    ReLU), the features are max-pooled over the points - so the scores do not depend on the
    points' order - and joined with the view state for FCs (``fcs``) to one score per view.
    ``encode`` is the pooled cloud feature, ``head(features, taken)`` the scores (as ``ScoreNet``).
    """

    turns = False  # its views are outputs: no quarter-turn augmentation

    def __init__(self, name: str, units: np.ndarray, dropout_from: str = "fc1", dropout: float = 0.5):
        super().__init__()
        arch = architecture(name)
        start = dropout_start_index(dropout_from, layer_names(name))
        self.name, self.task, self.inputs, self.views = name, arch.task, arch.inputs, len(units)
        self.register_buffer("point_scale", torch.ones(()))
        layers: list[nn.Module] = []
        width = 3
        for i, units_out in enumerate(arch.convs):
            layers += [nn.Linear(width, units_out), nn.ReLU(inplace=True), *_dropout(i, start, dropout)]
            width = units_out
        self.features = nn.Sequential(*layers)
        layers, width = [], width + self.views
        for i, units_out in enumerate(arch.fcs):
            layers += [nn.Linear(width, units_out), nn.ReLU(inplace=True),
                       *_dropout(len(arch.convs) + i, start, dropout)]
            width = units_out
        self.joint_head = nn.Sequential(*layers, nn.Linear(width, self.views))

    def encode(self, points: torch.Tensor) -> torch.Tensor:
        """(B, N, 3) points -> (B, F) the max over the points of their shared-MLP features."""
        return self.features(points * self.point_scale).amax(dim=1)

    def head(self, features: torch.Tensor, taken: torch.Tensor, turns: torch.Tensor | None = None) -> torch.Tensor:
        """(B, F) cloud features and (B, V) view states -> (B, V) scores."""
        return self.joint_head(torch.cat([features, taken.to(features.dtype)], dim=1))

    def forward(self, points: torch.Tensor, taken: torch.Tensor, turns: torch.Tensor | None = None) -> torch.Tensor:
        return self.head(self.encode(points), taken)


SCORE_NETS = {"nbvscore-3": ViewScoreNet, "nbvscore-fc3": ScoreNet, "nbvscore-fc3-wide": ScoreNet,
              "nbvscore-pc": PointScoreNet}


def build_model(name: str, dropout_from: str = "conv3", dropout: float = 0.5,
                views: np.ndarray | None = None) -> NBVNet | ScoreNet | PointScoreNet:
    """The registry's one factory; a score network (``nbvscore-*``) also needs ``views``, the
    (V, 3) unit directions of the candidate views it scores."""
    if architecture(name).task == "scores":
        if views is None or np.ndim(views) != 2 or np.shape(views)[1] != 3 or not len(views):
            raise ValueError(f"{name} scores candidate views: give views=(V, 3) unit directions (the shards')")
        return SCORE_NETS[name](name, views, dropout_from, dropout)
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
