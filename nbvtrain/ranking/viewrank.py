"""A ranker of candidate views from their features: one model for any view set.

It scores each candidate view from the per-view features of ``nbvdata.simulation.viewfeatures`` (what the
view's rays would meet in the grid, where it lies against the scans so far, the grid as a whole)
and is learned from the exact gain of every view of every state in the shards
(``nbvtrain.ranking.rankdata``: a state is a query, its unscanned views the items, the valid gains the
relevance). Nothing in it depends on how many views there are or where: the same model ranks the
paper's 500 hemisphere views, PC-NBV's 33, SCVP's 32 and ObjView-Bench's Tammes-128.

Two models on the same features (``KINDS``):

- ``viewrank-gbm``: LightGBM's lambdarank (gradient-boosted trees for NDCG), the relevance of a
  view ``round(grades x valid gain / the state's best valid gain)``, early stopping on the
  validation states' gain ratio.
- ``viewrank-mlp``: a small torch scorer (features standardised, two hidden layers of ``hidden``
  units), trained with a listwise loss: the cross-entropy between the softmax of its scores over a
  state's views and the softmax of the valid gains / (``temperature`` x the state's best).

The model file is plain data: ``viewrank-gbm`` a JSON file (``FORMAT``, the feature names, the
ray bundle, the scene, how it was trained, and ``lightgbm``: LightGBM's own text model, which
``lightgbm.Booster(model_str=...)`` reads); ``viewrank-mlp`` a torch file of tensors and plain
values read with ``weights_only=True``. Either loads without unpickling anything
(``load_ranker``), and a file that is neither says so in one line (``CheckpointError``).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from nbvdata.core.config import ConfigError, SimConfig
from nbvdata.core.files import write_atomic
from nbvdata.core.views import ViewSet
from nbvdata.simulation.viewfeatures import BUNDLE, FEATURE_GROUPS, FEATURES, shadow_weights, view_features
from nbvtrain.networks.checkpoint import CheckpointError, check_weights
from nbvtrain.ranking.rankdata import RankingData, bundle_for, check_grid, check_rows

KINDS = ("viewrank-gbm", "viewrank-mlp")
LABELS = ("graded", "scone", "vin")
"""gbm's labels (``RankerConfig.label``): lambdarank on grades of gain / the state's best (``graded``),
SCONE's L1 regression on gain / the state's mean gain (``scone``), VIN-NBV's ordinal bins of the
gains z-scored per capture stage, as lambdarank grades (``vin``)."""
FORMAT = "nbvtrain-viewrank"
FORMAT_VERSION = 1
USE_FIT = "pass a ranker written by nbvtrain fit --model viewrank-gbm|viewrank-mlp (runs/NAME/viewrank.json or .pt)"


@dataclass(frozen=True)
class RankerConfig:
    """How a ranker is trained (``nbvtrain fit --model viewrank-*``)."""

    model: str = "viewrank-gbm"
    """``viewrank-gbm`` (LightGBM lambdarank) or ``viewrank-mlp`` (a small torch scorer)."""
    rays: tuple[int, int] = BUNDLE
    """Rays per view of the features' coarse bundle (width, height)."""
    features: tuple[str, ...] = ("base",)
    """The columns it reads: groups of ``nbvdata.simulation.viewfeatures.FEATURE_GROUPS`` or column names."""
    label: str = "graded"
    """gbm: what it learns (``LABELS``)."""
    mesh_weights: tuple[tuple[str, float], ...] = ()
    """gbm: (file-name pattern, weight) pairs: a training state of a mesh whose source matches a
    pattern (``fnmatch``, the first that does) weighs that much, others 1 (e.g. the procedural
    ``random_*`` less, so that the real meshes weigh more)."""
    sample: int = 64
    """Training rows per state at most (its best quarter and a random rest); validation keeps all."""
    seed: int = 0
    """Seed of the row sampling and of the model."""
    grades: int = 15
    """gbm: relevance grades 0..grades from valid gain / the state's best."""
    trees: int = 600
    """gbm: boosting rounds at most (early stopping may end sooner)."""
    learning_rate: float = 0.05
    """gbm: shrinkage; mlp: Adam's step."""
    leaves: int = 31
    """gbm: leaves per tree."""
    min_rows: int = 100
    """gbm: rows per leaf at least."""
    patience: int = 40
    """gbm: rounds without a better validation gain ratio before stopping; mlp: epochs."""
    epochs: int = 12
    """mlp: passes over the training states at most."""
    hidden: tuple[int, ...] = (64, 64)
    """mlp: hidden layer widths."""
    temperature: float = 0.1
    """mlp: the target softmax's temperature, as a share of the state's best gain."""
    batch: int = 256
    """mlp: states per batch."""
    threads: int = 2
    """CPU threads of the model's training."""

    def __post_init__(self) -> None:
        if self.model not in KINDS:
            raise ConfigError(f"--model {self.model}: a ranker is one of {', '.join(KINDS)}")
        if self.label not in LABELS:
            raise ConfigError(f"--label {self.label}: one of {', '.join(LABELS)}")
        check_rows(self.rays, self.sample)
        feature_columns(self.features)

    @property
    def columns(self) -> list[str]:
        """The column names of ``features``, in ``FEATURES``' order."""
        return feature_columns(self.features)


def feature_columns(spec) -> list[str]:
    """The columns (``FEATURES``' order) of groups (``FEATURE_GROUPS``) and column names; ConfigError
    naming an unknown one."""
    chosen = set()
    for item in spec:
        if item in FEATURE_GROUPS:
            chosen |= set(FEATURE_GROUPS[item])
        elif item in FEATURES:
            chosen.add(item)
        else:
            raise ConfigError(f"--features {item}: neither a group ({', '.join(FEATURE_GROUPS)}) nor a feature column")
    return [name for name in FEATURES if name in chosen]


class ViewRanker:
    """A trained ranker: ``scores(features) -> (V,)``, higher is better; ``view_scores`` from a state.

    kind : one of ``KINDS``; features : the column names it reads (some of ``FEATURES``); rays : its
    bundle; scene : the grid it was trained on ({grid_size, grid_extent}); training : how it was made.
    A LightGBM model scores through its compiled trees (``nbvtrain.ranking.trees``: LightGBM's scores, bit
    for bit, in a fraction of its time on one decision's rows).
    """

    def __init__(self, kind: str, features: list[str], rays: tuple[int, int], scene: dict, training: dict,
                 booster=None, network=None, mean: np.ndarray | None = None, std: np.ndarray | None = None):
        from nbvtrain.ranking.trees import compile_trees

        self.kind, self.features, self.rays, self.scene, self.training = kind, list(features), tuple(rays), scene, training
        self.booster, self.network, self.mean, self.std = booster, network, mean, std
        self.columns = np.array([FEATURES.index(name) for name in self.features], dtype=np.int64)
        self.trees = compile_trees(booster.model_to_string()) if booster is not None else None
        self.prior = None  # the surface prior (nbvtrain.ranking.surfaceprior) of a ranker that reads expected_surface
        self.path: Path | None = None

    @property
    def name(self) -> str:
        return self.kind

    def scores(self, features: np.ndarray) -> np.ndarray:
        """(V,) float64 scores of (V, F) rows of its own columns (``features``)."""
        features = np.asarray(features, dtype=np.float32)
        if not len(features):
            return np.zeros(0)
        if self.trees is not None:
            return self.trees.raw(features)
        if self.booster is not None:
            return np.asarray(self.booster.predict(features, num_threads=1, raw_score=True), dtype=np.float64)
        import torch

        with torch.no_grad():
            x = (torch.from_numpy(features) - torch.from_numpy(self.mean)) / torch.from_numpy(self.std)
            return self.network(x).double().numpy().reshape(-1)

    def check_scene(self, config: SimConfig, where: str) -> None:
        """ConfigError when ``config``'s grid is not the one the ranker was trained on (``check_grid``)."""
        check_grid(self.scene, config, where, "a ranker")

    def view_scores(self, probabilities: np.ndarray, scanned: np.ndarray, views: ViewSet,
                    config: SimConfig) -> np.ndarray:
        """(V,) scores of ``views`` at the state of the (n, n, n) grid after scans from ``scanned``
        (P, 3) positions; ``config``: the scene's grid and sensor."""
        bundle = bundle_for(views, config, self.rays)
        shadow = shadow_weights(probabilities, scanned, bundle)
        surface = self.prior.probabilities(probabilities, shadow) if self.prior is not None else None
        return self.scores(view_features(probabilities, scanned, bundle, surface, shadow)[:, self.columns])

    def save(self, path: Path) -> None:
        """Write the model file (module docstring), whole or not at all."""
        head = {"format": FORMAT, "format_version": FORMAT_VERSION, "kind": self.kind, "features": self.features,
                "rays": list(self.rays), "scene": self.scene, "training": self.training}
        if self.prior is not None:  # carried whole: the file is all a ranker needs
            head["surface_prior"] = json.dumps(self.prior.to_dict(), allow_nan=False)
        if self.booster is not None:
            from nbvtrain.ranking._lightgbm import TEXT_KEY, text_digest

            model = self.booster.model_to_string()
            text = json.dumps(head | {TEXT_KEY: text_digest(model), "lightgbm": model}, indent=1, allow_nan=False)
            write_atomic(Path(path), text)
            return
        import torch

        from nbvtrain.networks.checkpoint import WEIGHTS_KEY, weights_digest

        weights = {"state_dict": {key: value.detach().clone() for key, value in self.network.state_dict().items()},
                   "mean": torch.from_numpy(self.mean.copy()), "std": torch.from_numpy(self.std.copy())}
        state = head | weights | {"hidden": list(self.training.get("hidden", [])),
                                  WEIGHTS_KEY: weights_digest(weights["state_dict"], _moments(weights))}
        partial = path.with_name(path.name + ".partial")
        torch.save(state, partial)
        partial.replace(path)


def env_choice(ranker: "ViewRanker", views: ViewSet, config: SimConfig):
    """``choose(observation, mask) -> view``: the ranker as a policy on the Gymnasium environment's
    observation (``nbvdata.env``: ``grid`` and ``taken``, over the environment's ``views`` in its scene
    ``config``), the best-ranked view among those ``mask`` (V,) bool allows (None: every unscanned one)."""
    def choose(observation: dict, mask: np.ndarray | None = None) -> int:
        taken = np.asarray(observation["taken"], dtype=bool)
        scores = ranker.view_scores(np.asarray(observation["grid"], dtype=np.float32), views.positions[taken], views,
                                    config)
        allowed = ~taken if mask is None else np.asarray(mask, dtype=bool)
        return int(np.argmax(np.where(allowed, scores, -np.inf))) if allowed.any() else 0
    return choose


def is_ranker_file(path: str | Path) -> bool:
    """Whether ``path`` looks like a ranker's file (its name: .json, or viewrank*.pt), not a network's checkpoint."""
    path = Path(path)
    return path.suffix.lower() == ".json" or (path.suffix == ".pt" and path.stem.startswith("viewrank"))


def load_ranker(path: str | Path) -> ViewRanker:
    """The ranker in ``path`` (module docstring); CheckpointError naming the file and the fix for
    anything else. Nothing is unpickled."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such ranker file; {USE_FIT}")
    if path.suffix.lower() == ".json":
        from nbvtrain.ranking._lightgbm import read_model_json

        head = read_model_json(path, "a ranker file", USE_FIT, CheckpointError)
        _check_head(head, path, "viewrank-gbm")
        _check_features(head, path)
        from nbvtrain.ranking._lightgbm import load_booster

        booster = load_booster(head, path, USE_FIT, CheckpointError)
        if booster.num_feature() != len(head["features"]):
            raise CheckpointError(f"{path}: its LightGBM model reads {booster.num_feature()} features, the file "
                                  f"names {len(head['features'])}; {USE_FIT}")
        ranker = ViewRanker(head["kind"], head["features"], tuple(head["rays"]), head["scene"], head["training"],
                            booster=booster)
    else:
        import torch

        try:
            state = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as error:  # any foreign file: say what it is not
            raise CheckpointError(f"{path}: not a ranker file ({type(error).__name__}: "
                                  f"{' '.join(str(error).split())[:100]}); {USE_FIT}") from None
        _check_head(state, path, "viewrank-mlp")
        _check_features(state, path)
        check_weights(state | {"moments": _moments(state)}, path, USE_FIT, "state_dict", "moments")
        try:
            network = scorer(len(state["features"]), tuple(state["hidden"]))
            network.load_state_dict(state["state_dict"])
        except (KeyError, RuntimeError, TypeError) as error:
            raise CheckpointError(f"{path}: its weights do not fit its scorer ({type(error).__name__}); "
                                  f"{USE_FIT}") from None
        network.eval()
        ranker = ViewRanker(state["kind"], state["features"], tuple(state["rays"]), state["scene"], state["training"],
                            network=network, mean=state["mean"].numpy(), std=state["std"].numpy())
    if "expected_surface" in ranker.features or "expected_surface_rel" in ranker.features:
        from nbvtrain.ranking.surfaceprior import surface_prior_from

        carried = (head if path.suffix.lower() == ".json" else state).get("surface_prior")
        if not isinstance(carried, str):
            raise CheckpointError(f"{path}: a ranker of the expected surface without its surface prior; {USE_FIT}")
        try:
            ranker.prior = surface_prior_from(json.loads(carried), path)
        except json.JSONDecodeError:
            raise CheckpointError(f"{path}: its surface prior is not JSON; {USE_FIT}") from None
    ranker.path = path
    return ranker


def _check_features(head: dict, path: Path) -> None:
    """CheckpointError when a ranker reads columns this nbvtrain does not compute."""
    names = head["features"]
    unknown = [name for name in names if name not in FEATURES] if isinstance(names, list) else ["(not a list)"]
    if unknown:
        raise CheckpointError(f"{path}: a ranker of other features ({', '.join(map(str, unknown[:3]))} are none of "
                              f"this nbvtrain's {len(FEATURES)} columns); retrain it with this version (nbvtrain fit "
                              f"--model {head['kind']})")


def _moments(state: dict) -> dict:
    """The standardisation tensors of a ``viewrank-mlp`` file, checked with its weights."""
    return {key: state[key] for key in ("mean", "std") if key in state}


def _check_head(head, path: Path, kind: str) -> None:
    if not isinstance(head, dict) or head.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a ranker file (no format {FORMAT!r}); {USE_FIT}")
    if head.get("format_version") != FORMAT_VERSION or head.get("kind") != kind:
        raise CheckpointError(f"{path}: a ranker file of format {head.get('format_version')} / kind "
                              f"{head.get('kind')!r}, this nbvtrain reads {FORMAT_VERSION} / {kind!r}; {USE_FIT}")
    missing = [key for key in ("features", "rays", "scene", "training") if key not in head]
    if missing:
        raise CheckpointError(f"{path}: not a ranker file (no {', '.join(missing)}); {USE_FIT}")


def scorer(features: int, hidden: tuple[int, ...]):
    """The torch scorer of ``viewrank-mlp``: (M, features) -> (M,)."""
    import torch.nn as nn

    layers, width = [], features
    for size in hidden:
        layers += [nn.Linear(width, size), nn.ReLU()]
        width = size
    layers.append(nn.Linear(width, 1))

    class Scorer(nn.Sequential):
        def forward(self, x):
            return super().forward(x).squeeze(-1)

    return Scorer(*layers)


# ---------------------------------------------------------------------------------------------
# Training


@dataclass
class FitReport:
    """What a ranker's training gave: validation gain ratios (overall, per layout), rounds or
    epochs, seconds."""

    ranker: ViewRanker
    val_gain_ratio: float
    per_layout: dict[str, float] = field(default_factory=dict)
    history: list[dict] = field(default_factory=list)
    seconds: float = 0.0


def grades(data: RankingData, levels: int) -> np.ndarray:
    """(M,) int32 relevance grades 0..``levels``: round(levels x valid gain / the state's best)."""
    best = np.repeat(data.best, data.sizes).astype(np.float64)
    share = np.divide(data.gains.astype(np.float64), best, out=np.zeros(len(best)), where=best > 0)
    return np.clip(np.rint(levels * share), 0, levels).astype(np.int32)


def vin_grades(data: RankingData, bins: int) -> np.ndarray:
    """(M,) int32 VIN-NBV's labels: each row's gain z-scored among the rows of its capture stage
    (the states of its scan step), clipped to [-3, 3], in ``bins`` equal-frequency ordinal bins
    (0 the lowest) over all rows."""
    steps = np.repeat(data.steps, data.sizes)
    gains = data.gains.astype(np.float64)
    z = np.zeros(len(gains))
    for step in np.unique(steps):
        rows = steps == step
        spread = gains[rows].std()
        z[rows] = (gains[rows] - gains[rows].mean()) / spread if spread > 0 else 0.0
    z = np.clip(z, -3.0, 3.0)
    edges = np.quantile(z, np.linspace(0, 1, bins + 1)[1:-1]) if len(z) else np.zeros(0)
    return np.searchsorted(edges, z, side="right").astype(np.int32)


def scone_targets(data: RankingData) -> np.ndarray:
    """(M,) float64 SCONE's targets: each row's gain over its state's mean gain (all its unscanned
    views; 0 in a state with nothing to gain)."""
    mean = np.repeat(data.mean, data.sizes).astype(np.float64)
    return np.divide(data.gains.astype(np.float64), mean, out=np.zeros(len(mean)), where=mean > 0)


def per_layout(data: RankingData, scores: np.ndarray) -> dict[str, float]:
    """The gain ratio of ``scores`` on each layout's states."""
    return {layout: data.gain_ratio(scores, data.layouts == layout) for layout in sorted(set(data.layouts.tolist()))}


def fit_gbm(train: RankingData, val: RankingData, config: RankerConfig, scene: dict,
            weights: np.ndarray | None = None) -> FitReport:
    """LightGBM on ``train``'s ``config.columns`` with ``config.label``'s objective (``LABELS``:
    lambdarank, or SCONE's L1 regression), the round with the best validation gain ratio kept;
    ``weights`` (S,): each training state's weight (``RankerConfig.mesh_weights``; None: 1)."""
    from nbvtrain.ranking._lightgbm import lightgbm

    started = time.perf_counter()
    columns = [FEATURES.index(name) for name in config.columns]
    params = {"objective": "lambdarank", "metric": "None", "learning_rate": config.learning_rate,
              "num_leaves": config.leaves, "min_data_in_leaf": config.min_rows, "feature_fraction": 0.9,
              "lambdarank_truncation_level": 20, "label_gain": [2.0 ** (g / 2) - 1 for g in range(config.grades + 1)],
              "num_threads": config.threads, "deterministic": True, "force_row_wise": True, "seed": config.seed,
              "verbosity": -1}
    if config.label == "scone":
        params = {key: value for key, value in params.items() if not key.startswith(("lambdarank", "label_gain"))}
        params["objective"] = "regression_l1"
        labels, groups = scone_targets(train), {}
    else:
        labels = grades(train, config.grades) if config.label == "graded" else vin_grades(train, config.grades)
        groups = {"group": train.sizes}
    rows = {} if weights is None else {"weight": np.repeat(np.asarray(weights, dtype=np.float64), train.sizes)}
    train_set = lightgbm.Dataset(train.features[:, columns], label=labels, feature_name=config.columns,
                                 free_raw_data=False, **groups, **rows)
    val_set = lightgbm.Dataset(val.features[:, columns], label=grades(val, config.grades), reference=train_set,
                               **({"group": val.sizes} if groups else {}))
    history: list[dict] = []

    def gain_ratio(predictions, dataset):
        value = val.gain_ratio(predictions) if dataset is val_set else float("nan")
        return "gain_ratio", value, True

    booster = lightgbm.train(params, train_set, num_boost_round=config.trees, valid_sets=[val_set],
                             valid_names=["val"], feval=gain_ratio,
                             callbacks=[lightgbm.early_stopping(config.patience, verbose=False),
                                        lightgbm.record_evaluation(recorded := {})])
    for round_, value in enumerate(recorded["val"]["gain_ratio"], start=1):
        history.append({"round": round_, "val_gain_ratio": value})
    best = booster.best_iteration or booster.current_iteration()
    booster = lightgbm.Booster(model_str=booster.model_to_string(num_iteration=best))
    training = asdict(config) | {"rounds": best}
    ranker = ViewRanker(config.model, config.columns, config.rays, scene, training, booster=booster)
    scores = ranker.scores(val.features[:, columns])
    return FitReport(ranker, val.gain_ratio(scores), per_layout(val, scores), history, time.perf_counter() - started)


def fit_mlp(train: RankingData, val: RankingData, config: RankerConfig, scene: dict,
            weights: np.ndarray | None = None) -> FitReport:
    """The torch scorer with the listwise loss (module docstring), the epoch with the best
    validation gain ratio kept."""
    import torch

    if weights is not None:
        raise ConfigError("--mesh-weight: an option of viewrank-gbm only")
    started = time.perf_counter()
    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    columns = [FEATURES.index(name) for name in config.columns]
    train_x, val_x = train.features[:, columns], val.features[:, columns]
    mean = train_x.astype(np.float64).mean(axis=0).astype(np.float32)
    std = (train_x.astype(np.float64).std(axis=0) + 1e-6).astype(np.float32)
    network = scorer(len(columns), config.hidden)
    optimizer = torch.optim.Adam(network.parameters(), lr=config.learning_rate)
    x, target, mask = _padded(train, train_x, mean, std, config.temperature)
    val_x = torch.from_numpy((val_x - mean) / std)
    rng = np.random.default_rng(config.seed)
    best_ratio, best_state, history, waited = -1.0, None, [], 0
    for epoch in range(1, config.epochs + 1):
        network.train()
        total = 0.0
        for batch in np.array_split(rng.permutation(len(x)), max(1, len(x) // config.batch)):
            scores = network(x[batch]).masked_fill(~mask[batch], -1e9)
            loss = -(target[batch] * torch.log_softmax(scores, dim=1)).sum(dim=1).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total += float(loss.detach()) * len(batch)
        network.eval()
        with torch.no_grad():
            ratio = val.gain_ratio(network(val_x).double().numpy())
        history.append({"epoch": epoch, "train_loss": total / len(x), "val_gain_ratio": ratio})
        if ratio > best_ratio:
            best_ratio, waited = ratio, 0
            best_state = {key: value.clone() for key, value in network.state_dict().items()}
        else:
            waited += 1
            if waited >= config.patience:
                break
    network.load_state_dict(best_state)
    network.eval()
    training = asdict(config) | {"epochs_run": len(history)}
    ranker = ViewRanker(config.model, config.columns, config.rays, scene, training, network=network, mean=mean,
                        std=std)
    scores = ranker.scores(val.features[:, columns])
    return FitReport(ranker, val.gain_ratio(scores), per_layout(val, scores), history, time.perf_counter() - started)


def _padded(data: RankingData, features: np.ndarray, mean: np.ndarray, std: np.ndarray, temperature: float):
    """(S, K, F) standardised ``features`` (M, F) of ``data``'s rows, (S, K) target distributions and
    (S, K) masks of the states with something to gain, K their most rows."""
    import torch

    keep = np.flatnonzero((data.best > 0) & (data.sizes > 0))
    width = int(data.sizes[keep].max()) if len(keep) else 1
    starts = data.starts
    x = np.zeros((len(keep), width, features.shape[1]), dtype=np.float32)
    target = np.zeros((len(keep), width), dtype=np.float32)
    mask = np.zeros((len(keep), width), dtype=bool)
    for k, s in enumerate(keep):
        rows = slice(starts[s], starts[s] + data.sizes[s])
        size = int(data.sizes[s])
        x[k, :size] = (features[rows] - mean) / std
        logits = data.gains[rows].astype(np.float64) / (temperature * data.best[s])
        weights = np.exp(logits - logits.max())
        target[k, :size] = weights / weights.sum()
        mask[k, :size] = True
    return torch.from_numpy(x), torch.from_numpy(target), torch.from_numpy(mask)


def baseline_ratios(data: RankingData) -> dict[str, float]:
    """Gain ratios of each single feature (higher first, or lower first where that ranks better),
    of ``farthest`` (the largest ``nearest_angle``) and of a random choice: what a learned ranker
    must beat."""
    out = {}
    for k, name in enumerate(FEATURES):
        column = data.features[:, k].astype(np.float64)
        out[name] = max(data.gain_ratio(column), data.gain_ratio(-column))
    rng = np.random.default_rng(0)
    out["random"] = data.gain_ratio(rng.random(len(data.gains)))
    keep = (data.best > 0) & (data.sizes > 0)
    out["farthest (its own choice)"] = float(np.mean(data.farthest[keep] / data.best[keep])) if keep.any() else math.nan
    return out
