"""Reconstruction as a Gymnasium environment, ``nbvdata/Reconstruct-v0``: the generator's own
simulation (``nbvdata.simulation.episode``) driven one scan at a time by any agent.

    import gymnasium, nbvdata.env
    env = gymnasium.make("nbvdata/Reconstruct-v0", meshes="my_meshes/", info_scores=True)

Importing this module registers the id (Gymnasium 1.x reads no plugin entry points);
``gymnasium.make("nbvdata.env:nbvdata/Reconstruct-v0", ...)`` imports it by itself.

An episode is one reconstruction: ``reset`` picks a mesh (seeded, or ``options["mesh"]``) and a
start view (seeded, or ``options["start_view"]``) and scans from it; every ``step`` scans once
more. The scene of every mesh is built as ``nbvdata generate`` builds it (``SceneCache``: same
reference points, same candidate views, same oracle), and kept, so a reset on a mesh seen before
costs a grid reset and one scan.

- Action: ``action="view"`` (default): ``Discrete(V)``, a candidate view, scanned from the view
  cache as the generator does (noise-free sensor). ``action="pose"``: ``Box(-1, 1, (3,))``, a
  direction from the object centre; the sensor goes there on the view sphere, looking at the
  centre, and the scan is cast live, as a regression network's pose is in ``nbvtrain evaluate``.
- Observation: ``grid`` (n, n, n) float32 occupancy probabilities, the authors' encoding
  (0.5 = unknown), and ``taken`` (V,) int8, 1 for every candidate view scanned (a pose marks its
  nearest candidate view).
- Reward: the increase of the observable coverage the scan gave, (newly covered observable
  reference points) / (observable points): the oracle's gain of the view scanned, so an episode's
  rewards add up to its final observable coverage minus the start scan's. ``overlap_penalty`` is
  subtracted when the scan broke the overlap rule (its overlap, as ``nbvdata.simulation.oracle.overlap``,
  under ``oracle.min_overlap``); 0 by default.
- ``terminated`` when no valid candidate view would add ``episode.min_gain`` (where the
  generator stops a run); else ``truncated`` once ``episode.max_scans`` scans are done (the start
  scan included). A step after either raises ``gymnasium.error.ResetNeeded``.
- ``info`` of ``reset`` and ``step``: ``mesh`` (its name), ``scans``, ``view`` (the candidate view
  scanned, or nearest to the pose), ``coverage`` and ``observable_coverage`` (fractions of all and
  of the observable reference points), ``overlap`` of the move (NaN after ``reset``). With
  ``info_scores=True`` also the oracle's scores of the new state, as the generator's shards
  hold them: ``gains`` and ``overlaps`` (V,) float32 and ``nbv`` (the next-best-view, -1 where
  ``terminated``).

Seeding follows Gymnasium: ``reset(seed=s)`` reseeds ``np_random``, from which a reset draws,
in this order, the mesh unless ``options`` gives it (again while the drawn mesh is unusable:
such a mesh is skipped with a warning), the start view unless ``options`` gives it, and the seed
of the range noise. The same seed and options give the same episode.

Action masks: ``action_masks()`` (the method sb3-contrib's ``MaskablePPO`` calls) and
``info["action_mask"]`` give (V,) bool, True for every candidate view an agent may take: the
views not scanned yet, so a masked agent never repeats a view; with ``mask_invalid=True`` only
those of them that also keep the overlap rule (overlap >= ``oracle.min_overlap``), or, where no
unscanned view keeps it, every unscanned view (a mask allows something while the episode runs).
A pose action is not masked; its ``action_masks()`` describe the candidate views all the same.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any, Sequence

try:
    import gymnasium
    from gymnasium import spaces
except ImportError:
    raise ImportError("nbvdata.env needs gymnasium, which is not installed: "
                      'pip install -e ".[rl]" (in a checkout) or pip install "gymnasium>=1.0"') from None

import numpy as np

from nbvdata.core.config import ConfigError, SimConfig, apply_overrides, from_dict, load_config, to_dict
from nbvdata.core.views import Pose, ViewSet, scanned_views, view_sphere
from nbvdata.simulation.episode import Reconstruction
from nbvdata.simulation.mesh import MeshError, check_content
from nbvdata.simulation.oracle import overlap, popcount
from nbvdata.simulation.shapes import BUILTIN_SHAPES, builtin_object
from nbvdata.simulation.sources import MeshSource, SceneCache, builtin_sources, mesh_sources

ENV_ID = "nbvdata/Reconstruct-v0"
ACTIONS = ("view", "pose")
OPTIONS = ("mesh", "start_view")


class ReconstructEnv(gymnasium.Env):
    """One simulated reconstruction per episode (see the module docstring).

    meshes : None (the built-in shapes), a folder of meshes, one mesh file or a .txt list of them
        (as ``nbvdata generate``), or a list of mesh files and ``"builtin:NAME"`` shapes
    config : the simulation settings: a ``SimConfig``, a YAML file, or None (the defaults);
        ``overrides`` (``"section.key=value"``, as ``--set``) apply on top
    action : "view" (``Discrete(V)``) or "pose" (``Box(-1, 1, (3,))``, a direction)
    info_scores : add the oracle's ``gains``, ``overlaps`` and ``nbv`` to ``info``
    overlap_penalty : subtracted from the reward of a scan that broke the overlap rule (>= 0)
    scene_cache : scenes kept (each 1-35 MB at the default settings, growing with the views
        visited); None keeps every mesh's
    threads : ray casting and numba threads (numba's for the whole process), 1 by default: an
        environment runs beside others or a learner, and two threads on a busy 2-core machine
        were 10x slower than one (docs/env.md); 0 = every core
    mask_invalid : the action mask also leaves out the views that break the overlap rule
    """

    metadata = {"render_modes": []}

    def __init__(self, meshes: str | Path | Sequence[str | Path] | None = None,
                 config: SimConfig | str | Path | None = None, overrides: Sequence[str] = (),
                 action: str = "view", info_scores: bool = False, overlap_penalty: float = 0.0,
                 scene_cache: int | None = 32, threads: int = 1, mask_invalid: bool = False):
        self.config = _settings(config, overrides)
        if action not in ACTIONS:
            raise ValueError(f"action={action!r}: must be 'view' (a candidate view index) or 'pose' "
                             "(a direction on the view sphere)")
        for name, value in (("info_scores", info_scores), ("mask_invalid", mask_invalid)):
            if not isinstance(value, bool):
                raise TypeError(f"{name}={value!r}: must be True or False")
        if isinstance(overlap_penalty, bool) or not isinstance(overlap_penalty, (int, float)) \
                or not math.isfinite(overlap_penalty) or overlap_penalty < 0:
            raise ValueError(f"overlap_penalty={overlap_penalty!r}: must be a finite number >= 0 (0 = no penalty)")
        if scene_cache is not None and (isinstance(scene_cache, bool) or not isinstance(scene_cache, int)
                                        or scene_cache < 0):
            raise ValueError(f"scene_cache={scene_cache!r}: must be an integer >= 0, or None to keep every scene")
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 0:
            raise ValueError(f"threads={threads!r}: must be an integer >= 0 (0 = every core)")
        self.action, self.info_scores, self.overlap_penalty = action, info_scores, float(overlap_penalty)
        self.mask_invalid = mask_invalid
        self.threads = threads
        self.sources = _sources(meshes, self.config)
        self.views: ViewSet = view_sphere(self.config.views)
        n, count = self.config.grid.size, len(self.views)
        self.observation_space = spaces.Dict({"grid": spaces.Box(0.0, 1.0, (n, n, n), np.float32),
                                              "taken": spaces.MultiBinary(count)})
        self.action_space = (spaces.Discrete(count) if action == "view"
                             else spaces.Box(-1.0, 1.0, (3,), np.float32))
        self._scenes = SceneCache(scene_cache)
        self._unusable: dict[int, str] = {}  # index into sources -> why it cannot be used
        self.source: MeshSource | None = None
        self.state: Reconstruction | None = None
        self.taken = np.zeros(count, dtype=np.int8)
        self._mask = np.zeros(count, dtype=bool)
        self._observed = 0  # observable reference points covered
        self._done = True

    @property
    def mesh_names(self) -> list[str]:
        """The names ``options["mesh"]`` takes (a mesh's stem works too), in draw order."""
        return [source.name for source in self.sources]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        mesh, view = self._options(options)  # bad options change nothing, not even the stream
        super().reset(seed=seed)
        if self.threads:
            import numba
            numba.set_num_threads(self.threads)
        if mesh is None:
            mesh, (_, scene, cache) = self._draw_mesh()
        else:
            try:
                _, scene, cache = self._scene(mesh)
            except (MeshError, ValueError, RuntimeError) as error:
                raise ValueError(f"options['mesh']={options['mesh']!r}: {self.sources[mesh].name} cannot be used: "
                                 f"{error}") from None
        if view is None:
            view = int(self.np_random.integers(len(self.views)))
        noise = np.random.default_rng(int(self.np_random.integers(2**63)))
        self.source = self.sources[mesh]
        self.state = Reconstruction(scene, cache, noise)
        self.taken[:] = 0
        self.state.scan(view)
        self.taken[view] = 1
        self._observed = popcount(self.state.covered & scene.oracle.observable)
        self._done = False
        scores = scene.oracle.score(self.state.covered) if self.info_scores or self.mask_invalid else None
        self._mask = self._allowed(scores)
        return self._observation(), self._info(view, float("nan"), scores if self.info_scores else None)

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        if self._done:
            raise gymnasium.error.ResetNeeded("step() after the episode ended (or before any reset): call reset()")
        if self.action == "view":
            view, pose = check_view(action, len(self.views)), None
        else:
            view, pose = direction_pose(action, self.views)
        state, oracle, config = self.state, self.state.scene.oracle, self.config
        before = state.covered.copy()
        seen = state.scan(view) if pose is None else state.scan_pose(pose)
        self.taken[view] = 1
        move_overlap = overlap(seen, before)
        observed = popcount(state.covered & oracle.observable)
        reward = (observed - self._observed) / max(oracle.observable_count, 1)
        if move_overlap < config.oracle.min_overlap:
            reward -= self.overlap_penalty
        self._observed = observed
        scores = oracle.score(state.covered)
        terminated = scores.best(config.oracle.min_overlap, config.episode.min_gain) is None
        truncated = not terminated and state.scans >= config.episode.max_scans
        self._done = terminated or truncated
        self._mask = self._allowed(scores)
        info = self._info(view, move_overlap, scores if self.info_scores else None)
        return self._observation(), float(reward), terminated, truncated, info

    def action_masks(self) -> np.ndarray:
        """(V,) bool: the candidate views an agent may take now (see the module docstring); a copy."""
        return self._mask.copy()

    def close(self) -> None:
        self._scenes = SceneCache(self._scenes.size)
        self.state, self._done = None, True

    def _observation(self) -> dict[str, np.ndarray]:
        return observation(self.state.grid.probabilities(), self.taken)

    def _info(self, view: int, move_overlap: float, scores) -> dict[str, Any]:
        state, oracle = self.state, self.state.scene.oracle
        info = {"mesh": self.source.name, "scans": state.scans, "view": int(view),
                "coverage": popcount(state.covered) / oracle.points,
                "observable_coverage": self._observed / max(oracle.observable_count, 1),
                "overlap": float(move_overlap), "action_mask": self._mask.copy()}
        if scores is not None:
            nbv = scores.best(self.config.oracle.min_overlap, self.config.episode.min_gain)
            info |= {"gains": scores.gains.astype(np.float32), "overlaps": scores.overlaps.astype(np.float32),
                     "nbv": -1 if nbv is None else nbv}
        return info

    def _allowed(self, scores) -> np.ndarray:
        """(V,) bool action mask of the current state: unscanned views, and with ``mask_invalid``
        those of them that keep the overlap rule where there is any."""
        unscanned = self.taken == 0
        if not self.mask_invalid:
            return unscanned
        keeping = unscanned & (scores.overlaps >= self.config.oracle.min_overlap)
        return keeping if keeping.any() else unscanned

    def _options(self, options: Any) -> tuple[int | None, int | None]:
        """(mesh index, start view) that ``options`` gives, None where it gives none."""
        if options is None:
            return None, None
        if not isinstance(options, dict):
            raise TypeError(f"reset(options={options!r}): must be a dict with keys {', '.join(OPTIONS)}, or None")
        unknown = [key for key in options if key not in OPTIONS]
        if unknown:
            raise ValueError(f"reset(options=...): unknown key(s) {', '.join(map(repr, unknown))}; "
                             f"known: {', '.join(OPTIONS)}")
        mesh = options.get("mesh")
        if mesh is not None:
            mesh = self._mesh_index(mesh)
        start = options.get("start_view")
        if start is not None:
            start = check_view(start, len(self.views), "options['start_view']")
        return mesh, start

    def _mesh_index(self, mesh: Any) -> int:
        """The index of ``options["mesh"]``: an index into ``mesh_names``, a name or a stem."""
        if isinstance(mesh, (int, np.integer)) and not isinstance(mesh, (bool, np.bool_)):
            if not 0 <= mesh < len(self.sources):
                raise ValueError(f"options['mesh']={mesh!r}: out of range; this environment has "
                                 f"{len(self.sources)} meshes (0..{len(self.sources) - 1})")
            return int(mesh)
        if not isinstance(mesh, str):
            raise TypeError(f"options['mesh']={mesh!r}: must be a mesh's index or name (see mesh_names)")
        found = [i for i, source in enumerate(self.sources) if mesh in (source.name, source.stem)]
        if len(found) != 1:
            names = ", ".join(self.mesh_names[:5]) + (", ..." if len(self.sources) > 5 else "")
            problem = "names several meshes: give its index in mesh_names" if found else f"is none of the meshes ({names})"
            raise ValueError(f"options['mesh']={mesh!r}: {problem}")
        return found[0]

    def _draw_mesh(self) -> tuple[int, tuple]:
        """A uniformly drawn usable mesh's index and ``SceneCache`` entry; unusable ones are
        skipped with a warning, the draws being the same whether or not they were found unusable
        before."""
        while len(self._unusable) < len(self.sources):
            index = int(self.np_random.integers(len(self.sources)))
            if index in self._unusable:
                continue
            try:
                return index, self._scene(index)
            except (MeshError, ValueError, RuntimeError) as error:
                self._unusable[index] = str(error)
                warnings.warn(f"nbvdata.env: skipping mesh {self.sources[index].name}: {error}", stacklevel=3)
        reasons = "; ".join(list(self._unusable.values())[:3])
        raise ValueError(f"no usable mesh among the {len(self.sources)} given: {reasons}")

    def _scene(self, index: int) -> tuple:
        """``SceneCache`` entry (mesh, scene, view cache) of mesh ``index``."""
        return self._scenes.get(self.sources[index], self.config, self.threads)


def observation(probabilities: np.ndarray, taken: np.ndarray) -> dict[str, np.ndarray]:
    """The environment's observation: ``grid`` (n, n, n) float32 occupancy probabilities (0.5 =
    unknown) and ``taken`` (V,) int8 scanned candidate views, from any boolean or 0/1 array."""
    return {"grid": np.asarray(probabilities, dtype=np.float32), "taken": np.asarray(taken, dtype=np.int8).copy()}


def check_view(action: Any, count: int, name: str = "action") -> int:
    """A candidate view index in 0..count-1 from an integer (Python or NumPy, 0-d arrays too);
    TypeError or ValueError naming ``action`` otherwise."""
    value = action.item() if isinstance(action, np.ndarray) and action.ndim == 0 else action
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} {action!r}: must be an integer candidate view index in 0..{count - 1}")
    if not 0 <= value < count:
        raise ValueError(f"{name} {action!r}: out of range; a candidate view index in 0..{count - 1}")
    return int(value)


def direction_pose(action: Any, views: ViewSet, name: str = "action") -> tuple[int, Pose]:
    """(nearest candidate view, pose) of a direction (3,) from the object centre: the sensor on
    the view sphere there, looking at the centre, as ``nbvtrain.networks.predict`` places a regression
    network's output. ValueError naming ``action`` for another shape, NaN, infinity or zero."""
    try:
        direction = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError):
        direction = None
    if direction is None or direction.shape != (3,):
        raise ValueError(f"{name} {action!r}: must be a direction (x, y, z) of shape (3,)")
    norm = float(np.linalg.norm(direction))
    if not math.isfinite(norm) or norm == 0:
        raise ValueError(f"{name} {action!r}: must be a finite, non-zero direction")
    radius = float(np.linalg.norm(views.positions[0]))
    pose = Pose.look_at(direction / norm * radius)
    return int(np.flatnonzero(scanned_views(pose.position, views.unit_positions))[0]), pose


def _settings(config: SimConfig | str | Path | None, overrides: Sequence[str]) -> SimConfig:
    """The simulation settings of ``config`` with ``overrides``; ConfigError (a ValueError) for bad ones."""
    if isinstance(overrides, str) or not all(isinstance(text, str) for text in overrides):
        raise TypeError(f"overrides={overrides!r}: must be a list of 'section.key=value' strings")
    if isinstance(config, SimConfig):
        settings = from_dict(SimConfig, apply_overrides(to_dict(config), list(overrides))) if overrides else config
    elif config is None or isinstance(config, (str, Path)):
        settings = load_config(SimConfig, config, list(overrides))
    else:
        raise TypeError(f"config={config!r}: must be a SimConfig, a YAML file's path or None")
    if settings.episode.max_scans < 2:
        raise ConfigError(f"episode.max_scans={settings.episode.max_scans}: an episode needs >= 2 scans "
                          "(the start scan and one step)")
    return settings


def _sources(meshes: Any, config: SimConfig) -> list[MeshSource]:
    """The meshes an environment draws from; files whose bytes cannot be a mesh of their format
    are left out with a warning; ValueError (``MeshError``) when none is left."""
    if meshes is None:
        return builtin_sources(config.mesh)
    items = [meshes] if isinstance(meshes, (str, Path)) else meshes
    if not isinstance(items, (list, tuple)) or not items or not all(isinstance(i, (str, Path)) for i in items):
        raise TypeError(f"meshes={meshes!r}: must be a folder, a mesh file, a .txt list, a non-empty list of "
                        "mesh files and 'builtin:NAME' shapes, or None for the built-in shapes")
    sources, failures = [], []
    for item in items:
        if isinstance(item, str) and item.startswith("builtin:"):
            name = item.removeprefix("builtin:")
            if name not in BUILTIN_SHAPES:
                raise ValueError(f"meshes: {item!r} is no built-in shape; known: {', '.join(BUILTIN_SHAPES)}")
            sources.append(MeshSource(item, builtin_object(name, config.mesh).mesh_id))
            continue
        found, unreadable = mesh_sources(Path(item))
        sources += found
        failures += unreadable
    usable = []
    for source in sources:
        try:
            if source.path is not None:
                check_content(source.path)
            usable.append(source)
        except MeshError as error:
            failures.append((str(source.path), str(error)))
    for name, reason in failures:
        warnings.warn(f"nbvdata.env: skipping mesh {name}: {reason}", stacklevel=3)
    if not usable:
        raise MeshError(f"meshes={meshes!r}: no usable mesh" + (f" ({failures[0][1]})" if failures else ""))
    return usable


if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="nbvdata.env:ReconstructEnv")
