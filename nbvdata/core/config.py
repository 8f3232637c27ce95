"""Settings of the simulation, as frozen dataclasses filled from YAML.

The dataclasses are the source of truth: every field has a default and a docstring-style
comment. YAML (``yaml.safe_load``) and ``--set section.key=value`` overrides only fill them.
Unknown keys are rejected with a "did you mean" hint and every value is checked against its
rule, so a typo in a config fails at once with one line that names the fix.
"""

from __future__ import annotations

import dataclasses
import difflib
import re
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml

from nbvdata.core.errors import UserError


class ConfigError(UserError):
    """A config file or override that cannot be used; the message names the fix."""


def require(condition: bool, message: str) -> None:
    """ConfigError(``message``) unless ``condition``: how a setting states its rule."""
    if not condition:
        raise ConfigError(message)


@dataclass(frozen=True)
class MeshConfig:
    object_size: float = 0.136
    """Largest bounding-box side of the object after normalisation, in metres. 0.136 m is the
    largest object whose fitted grid cube (0.138 m) lies wholly inside the sensor's frustum from
    every candidate view at 0.4 m, so one scan can carve the whole cube, as in the authors' grids
    (README, "The scene")."""
    up_axis: Literal["z", "y"] = "z"
    """Axis that points up in the mesh files; "y" rotates y-up files so that +z is up."""

    def __post_init__(self) -> None:
        require(self.object_size > 0, f"mesh.object_size={self.object_size}: must be > 0 metres")


# View layouts read from a fixed list of directions (``nbvdata.core.views.FIXED_LAYOUTS``) and their
# number of views.
FIXED_LAYOUT_COUNTS = {"pc-nbv-33": 33, "scvp-32": 32, "tammes-128": 128}


@dataclass(frozen=True)
class ViewConfig:
    radius: float = 0.4
    """Radius of the view sphere around the object centre, in metres (the authors' 0.4 m)."""
    count: int = 500
    """Number of candidate views."""
    layout: Literal["hemisphere", "sphere", "pc-nbv-33", "scvp-32", "tammes-128"] = "hemisphere"
    """"hemisphere": ``count`` Fibonacci-lattice views with z >= 0 (object on a table, as in the
    authors' data); "sphere": all round; "pc-nbv-33": PC-NBV's 33 views (``count`` must be 33;
    ``nbvdata.core.views.FIXED_LAYOUTS``), turned from their y-up frame to z-up, 8 of them below the
    equator; "scvp-32": SCVP's 32 views (``nbvdata.core.layout_scvp``), their directions at ``radius``
    (``count`` must be 32); "tammes-128": ObjView-Bench's 128 directions over the whole sphere
    (``nbvdata.core.layout_tammes``; ``count`` must be 128)."""
    reach: Literal["whole", "hemi"] = "whole"
    """Which views of the layout a robot can reach (ObjView-Bench's presets): "whole" every one;
    "hemi" those with z >= 0 (the camera above the table's plane)."""

    def __post_init__(self) -> None:
        require(self.radius > 0, f"views.radius={self.radius}: must be > 0 metres")
        require(self.count >= 1, f"views.count={self.count}: must be >= 1")
        fixed = FIXED_LAYOUT_COUNTS.get(self.layout)
        require(fixed is None or self.count == fixed,
               f"views.count={self.count}: views.layout={self.layout} has {fixed} views: set views.count={fixed}")


@dataclass(frozen=True)
class SensorConfig:
    width: int = 176
    """Rays per image row (the authors' time-of-flight camera: 176)."""
    height: int = 144
    """Rays per image column (authors: 144)."""
    hfov: float = 0.77
    """Horizontal field of view in radians (authors: 0.77)."""
    vfov: float = 0.61
    """Vertical field of view in radians (authors: 0.61)."""
    near: float = 0.05
    """Closest range that returns a measurement, in metres."""
    far: float = 1.0
    """Farthest range that returns a measurement; rays without a return carve free space to here."""
    noise_std: float = 0.0
    """Standard deviation of Gaussian range noise along each ray, in metres (0 = exact)."""

    def __post_init__(self) -> None:
        require(self.width >= 1 and self.height >= 1,
               f"sensor.width/height={self.width}x{self.height}: must be >= 1")
        require(0 < self.hfov < 3.1 and 0 < self.vfov < 3.1,
               f"sensor.hfov/vfov={self.hfov}/{self.vfov}: must lie in (0, 3.1) radians")
        require(0 <= self.near < self.far, f"sensor.near={self.near}, far={self.far}: need 0 <= near < far")
        require(self.noise_std >= 0, f"sensor.noise_std={self.noise_std}: must be >= 0")


@dataclass(frozen=True)
class GridConfig:
    size: int = 32
    """Voxels along each axis."""
    extent: float | None = None
    """Side of the grid cube in metres, centred on the object. None (the default, the paper's
    scene): fitted to the object, so the object spans the grid along its largest side and the
    voxel size follows the object: the side is ``mesh.object_size`` plus half a voxel, putting
    the object's extreme faces a quarter voxel inside the outer voxels (OctoMap's voxels are
    half-open, so a point exactly on the cube's upper face would fall outside the grid);
    ``SimConfig.scene_grid`` resolves it. A number: a fixed cube, whatever the object."""
    prob_hit: float = 0.7
    """Occupancy probability of a voxel that holds a return (OctoMap default 0.7)."""
    prob_miss: float = 0.4
    """Occupancy probability of a voxel a ray passes through (OctoMap default 0.4)."""
    clamp_min: float = 0.1192
    """Lower clamping probability (OctoMap default 0.1192)."""
    clamp_max: float = 0.971
    """Upper clamping probability (OctoMap default 0.971)."""

    def __post_init__(self) -> None:
        require(self.size >= 2 and self.size % 2 == 0,
               f"grid.size={self.size}: must be even and >= 2 (so voxels align with OctoMap keys)")
        require(self.extent is None or self.extent > 0,
               f"grid.extent={self.extent}: must be > 0 metres, or null to fit the cube to the object")
        require(0.5 < self.prob_hit < 1, f"grid.prob_hit={self.prob_hit}: must lie in (0.5, 1)")
        require(0 < self.prob_miss < 0.5, f"grid.prob_miss={self.prob_miss}: must lie in (0, 0.5)")
        require(0 < self.clamp_min < 0.5 < self.clamp_max < 1,
               f"grid.clamp_min/max={self.clamp_min}/{self.clamp_max}: need 0 < min < 0.5 < max < 1")

    @property
    def resolution(self) -> float:
        """Voxel side in metres (of a resolved cube: see ``SimConfig.scene_grid``)."""
        if self.extent is None:
            raise ValueError("grid.extent is null (fitted to the object): resolve the cube with "
                             "SimConfig.scene_grid, or give grid.extent in metres")
        return self.extent / self.size


@dataclass(frozen=True)
class CoverageConfig:
    points: int = 16384
    """Reference points sampled on the mesh surface (16,384 as in PC-NBV and SCONE)."""
    threshold: float = 0.003
    """Match distance in metres: a reference point is covered when a scanned point lies this close.

    3 mm is 1.7x the sensor's point spacing at 0.4 m (0.77 rad / 176 rays * 0.4 m = 1.75 mm), so
    a surface facing the sensor is matched everywhere, and one seen up to about 65 degrees off
    its normal still is (the spacing grows as 1/cos); it is 0.0075 of a 0.4 m object diagonal,
    close to the 0.00707-of-unit-diagonal threshold of PC-NBV and SCONE."""
    metric: Literal["euclidean", "box"] = "euclidean"
    """"euclidean": distance <= threshold; "box": |dx|, |dy|, |dz| < threshold (the authors' code)."""

    def __post_init__(self) -> None:
        require(self.points >= 1, f"coverage.points={self.points}: must be >= 1")
        require(self.threshold > 0, f"coverage.threshold={self.threshold}: must be > 0 metres")


@dataclass(frozen=True)
class OracleConfig:
    min_overlap: float = 0.2
    """A candidate view is valid when at least this fraction of the surface it would observe is
    already covered (the authors' 20 % registration overlap)."""
    cover: bool = False
    """Also label every state with the fewest candidate views that cover all the observable surface
    it has not covered yet (SCVP's set-cover label, ``nbvdata.simulation.setcover``): the shards then hold
    ``cover``, ``cover_size``, ``cover_bound`` and ``cover_greedy``. False: the data of before."""
    cover_node_limit: int = 200
    """Branch-and-bound nodes (HiGHS's count) a state's set cover may use in all its solver calls:
    a count, not seconds (SCVP's Gurobi had 10 s), so every label is the same on any machine under
    any load. A state that uses them up keeps the best set found and the proven lower bound
    (``cover_bound`` < ``cover_size``)."""

    def __post_init__(self) -> None:
        require(0 <= self.min_overlap <= 1, f"oracle.min_overlap={self.min_overlap}: must be in [0, 1]")
        require(self.cover_node_limit >= 1,
               f"oracle.cover_node_limit={self.cover_node_limit}: must be >= 1 branch-and-bound node")


@dataclass(frozen=True)
class EpisodeConfig:
    runs_per_mesh: int = 20
    """Reconstruction runs per mesh, each from its own random start view."""
    max_scans: int = 10
    """Scans per run at most (the paper evaluates 10); a run records at most this many states."""
    min_gain: float = 0.002
    """A run stops when no valid view would raise the observable coverage by at least this."""
    seed: int = 0
    """Global seed; each mesh's and run's seeds derive from it and the mesh id."""
    explore: float = 0.0
    """Exploration: at each move, with this probability the run moves to a uniformly random valid
    candidate view (overlap >= ``oracle.min_overlap``) instead of the labelled NBV; every state is
    still labelled by the exhaustive search. 0 = the oracle's own path (the data of before)."""
    oracle_mix: float = 0.0
    """With ``nbvdata generate --policy``: the probability that a move (one not exploring) follows the
    oracle's NBV instead of the policy (DAgger's beta). 0 = the policy's moves only."""

    def __post_init__(self) -> None:
        require(self.runs_per_mesh >= 1, f"episode.runs_per_mesh={self.runs_per_mesh}: must be >= 1")
        require(self.max_scans >= 1, f"episode.max_scans={self.max_scans}: must be >= 1")
        require(0 <= self.min_gain <= 1, f"episode.min_gain={self.min_gain}: must be in [0, 1]")
        require(self.seed >= 0, f"episode.seed={self.seed}: must be >= 0")
        require(0 <= self.explore <= 1, f"episode.explore={self.explore}: must be in [0, 1] (0 = no exploration)")
        require(0 <= self.oracle_mix <= 1, f"episode.oracle_mix={self.oracle_mix}: must be in [0, 1]")


@dataclass(frozen=True)
class StateConfig:
    """What a recorded state holds besides the grid and the scores."""

    points: int = 0
    """Points of each state's partial cloud (``nbvdata.core.cloud``): every point scanned so far,
    reduced to this many by farthest-point sampling (fewer are repeated), stored as the shards'
    ``points``, ``points_count`` and ``reference_points``. 0 = no clouds (the shards of before)."""
    surface: bool = False
    """Store the mesh's surface voxels in the scene grid once per shard (``surface``: the ground
    truth of where the surface is, for a model of the surface hidden in a partial grid). False =
    none (the shards of before)."""

    def __post_init__(self) -> None:
        require(self.points >= 0, f"state.points={self.points}: must be an integer >= 0 (0 = no point clouds; "
               "PC-NBV reads 1024)")


@dataclass(frozen=True)
class GenerateConfig:
    """How ``nbvdata generate`` spreads its work. Never changes the generated arrays."""

    workers: int = 0
    """Parallel workers (one thread each); 0 = one per CPU core."""
    backend: Literal["loky", "threading", "dask"] = "loky"
    """joblib backend; "dask" runs the units on the Dask cluster at ``scheduler``."""
    scheduler: str | None = None
    """Dask scheduler address (e.g. tcp://10.0.0.5:8786) for backend "dask"; none = a local cluster."""
    runs_per_shard: int = 0
    """Runs per work unit and shard; 0 = all runs of a mesh in one shard."""

    def __post_init__(self) -> None:
        require(self.workers >= 0, f"generate.workers={self.workers}: must be >= 0 (0 = all cores)")
        require(self.runs_per_shard >= 0, f"generate.runs_per_shard={self.runs_per_shard}: must be >= 0")


@dataclass(frozen=True)
class SimConfig:
    """Every setting: the scene (mesh .. coverage), the labelling and runs, and the job layout."""

    mesh: MeshConfig = field(default_factory=MeshConfig)
    views: ViewConfig = field(default_factory=ViewConfig)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    grid: GridConfig = field(default_factory=GridConfig)
    coverage: CoverageConfig = field(default_factory=CoverageConfig)
    oracle: OracleConfig = field(default_factory=OracleConfig)
    episode: EpisodeConfig = field(default_factory=EpisodeConfig)
    state: StateConfig = field(default_factory=StateConfig)
    generate: GenerateConfig = field(default_factory=GenerateConfig)

    @property
    def scene_grid(self) -> GridConfig:
        """The grid with its cube in metres: fitted to the object when ``grid.extent`` is null
        (side = object_size * n / (n - 1/2), i.e. the object's largest side plus half a voxel)."""
        if self.grid.extent is None:
            n = self.grid.size
            return dataclasses.replace(self.grid, extent=self.mesh.object_size * n / (n - 0.5))
        return self.grid

    def dataset_dict(self) -> dict[str, Any]:
        """The settings that determine the generated data (all but ``generate``); those of
        ``NEUTRAL_DEFAULTS`` only when they differ from their default (a section left empty goes too)."""
        data = to_dict(self)
        del data["generate"]
        for (section, key), default in NEUTRAL_DEFAULTS.items():
            if data[section][key] == default:
                del data[section][key]
                if not data[section]:
                    del data[section]
        return data


# Settings added after datasets were published, whose default leaves the data as it was before
# them: ``dataset_dict`` leaves them out at that default, so the same data keeps the same
# recorded settings (config.yaml, every shard's ``config`` attribute) and the same bytes.
NEUTRAL_DEFAULTS = {("views", "reach"): "whole", ("episode", "explore"): 0.0, ("episode", "oracle_mix"): 0.0,
                    ("state", "points"): 0, ("state", "surface"): False, ("oracle", "cover"): False,
                    ("oracle", "cover_node_limit"): OracleConfig.cover_node_limit}


# ---------------------------------------------------------------------------------------------
# Building dataclasses from plain data


EXPONENT_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")
"""A number in exponent notation, which YAML 1.1 reads as a string unless its mantissa has a dot (1e-5)."""


def from_dict(cls: type, data: dict[str, Any] | None, where: str = "") -> Any:
    """Build dataclass ``cls`` from a nested dict, rejecting unknown keys and wrong types."""
    data = {} if data is None else data
    if not isinstance(data, dict):
        raise ConfigError(f"{where or 'config'}: expected a mapping of keys, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    values = {}
    for key, value in data.items():
        if key not in fields:
            close = difflib.get_close_matches(str(key), list(fields), n=1)
            hint = f"; did you mean '{_join(where, close[0])}'?" if close else ""
            raise ConfigError(f"unknown setting '{_join(where, key)}'{hint} "
                              f"(known: {', '.join(fields)})")
        values[key] = _coerce(hints[key], value, _join(where, key))
    return cls(**values)


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else str(key)


def _coerce(hint: Any, value: Any, where: str) -> Any:
    if dataclasses.is_dataclass(hint):
        return from_dict(hint, value, where)
    origin = typing.get_origin(hint)
    if origin is Literal:
        choices = typing.get_args(hint)
        if value not in choices:
            raise ConfigError(f"{where}={value!r}: must be one of {', '.join(map(repr, choices))}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}={value!r}: must be true or false")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}={value!r}: must be an integer")
        return value
    if hint is float:
        if isinstance(value, str) and EXPONENT_NUMBER.fullmatch(value.strip()):
            return float(value)  # 1e-5: YAML 1.1 (PyYAML) reads a number without a dot as text
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}={value!r}: must be a number")
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}={value!r}: must be a string")
        return value
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}={value!r}: must be a list")
        (item,) = typing.get_args(hint)[:1]
        return tuple(_coerce(item, v, f"{where}[{i}]") for i, v in enumerate(value))
    if origin is typing.Union or str(origin) == "<class 'types.UnionType'>":
        args = typing.get_args(hint)
        if value is None and type(None) in args:
            return None
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(arg, value, where)
            except ConfigError:
                pass
        raise ConfigError(f"{where}={value!r}: must be {hint}")
    return value


def to_dict(config: Any) -> dict[str, Any]:
    """Plain nested dict of a config dataclass (tuples become lists), safe for YAML."""
    def plain(value: Any) -> Any:
        if isinstance(value, (list, tuple)):
            return [plain(v) for v in value]
        if isinstance(value, dict):
            return {k: plain(v) for k, v in value.items()}
        return value
    return plain(dataclasses.asdict(config))


def to_yaml(config: Any) -> str:
    """The resolved config as YAML text (plain types only, loadable with ``yaml.safe_load``)."""
    return yaml.safe_dump(to_dict(config), sort_keys=False)


def parse_override(text: str) -> tuple[list[str], Any]:
    """Split ``section.key=value`` into a key path and a YAML-parsed value."""
    if "=" not in text:
        raise ConfigError(f"--set {text!r}: expected key=value, e.g. --set views.count=1000")
    key, raw = text.split("=", 1)
    path = [part for part in key.strip().split(".") if part]
    if not path:
        raise ConfigError(f"--set {text!r}: the key before '=' is empty")
    return path, yaml.safe_load(raw) if raw.strip() else ""


def load_config(cls: type, path: str | Path | None = None, overrides: list[str] = ()) -> Any:
    """Defaults of ``cls``, then the YAML file at ``path``, then ``key=value`` overrides."""
    data: dict[str, Any] = {}
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"config file {path} not found: check the --config path")
        try:
            data = yaml.safe_load(path.read_text()) or {}
        except yaml.YAMLError as error:
            raise ConfigError(f"config file {path} is not valid YAML: {error}".splitlines()[0]) from None
        if not isinstance(data, dict):
            raise ConfigError(f"config file {path}: the top level must be a mapping of sections")
    return from_dict(cls, apply_overrides(data, overrides))


def apply_overrides(data: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """``data`` (nested sections, changed in place) with each ``section.key=value`` set."""
    for text in overrides:
        keys, value = parse_override(text)
        node = data
        for key in keys[:-1]:
            node = node.setdefault(key, {})
            if not isinstance(node, dict):
                raise ConfigError(f"--set {text!r}: '{key}' is a value, not a section")
        node[keys[-1]] = value
    return data
