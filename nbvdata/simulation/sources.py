"""Where the meshes of a job come from, and their scenes: the sources ``nbvdata generate``,
``nbvdata.env`` and ``nbvtrain evaluate`` share.

- ``MeshSource``: a mesh file or a built-in shape, with its id (the file's sha256) and the name
  tables show (``title``: the stem, or the path under the folder given where stems collide, as
  ShapeNet's ``CAT/ID/models/model_normalized.obj``); ``builtin_sources`` (the default job),
  ``mesh_sources`` (a folder, a file or a .txt list),
  ``part_sources`` (the train, val or test meshes of a published version, found by name and
  sha256 under a root: ``find_part_meshes``).
- ``SceneCache``: the scenes (mesh, scene, view cache) of the last few meshes asked for; a scene
  is a function of the mesh, the data settings and the seed, so taking it from here changes no byte.
"""

from __future__ import annotations

import dataclasses
import os
from collections import Counter, OrderedDict, defaultdict
from dataclasses import dataclass
from pathlib import Path

from nbvdata.core.config import GenerateConfig, MeshConfig, SimConfig
from nbvdata.core.files import sha256_file
from nbvdata.core.text import some_names
from nbvdata.schema.manifest import ManifestError, Published, load_manifest
from nbvdata.simulation.episode import ViewCache, scene_rng
from nbvdata.simulation.mesh import MeshError, ObjectMesh, find_meshes, load_mesh
from nbvdata.simulation.scene import Scene
from nbvdata.simulation.shapes import BUILTIN_SHAPES, builtin_object


@dataclass(frozen=True)
class MeshSource:
    """A mesh to generate from: a file, or a built-in shape (``path`` None)."""

    name: str
    mesh_id: str
    path: Path | None = None
    label: str = ""
    """The path under the folder given, where another source has the same stem (``with_labels``)."""

    def load(self, config: MeshConfig) -> ObjectMesh:
        if self.path is None:
            return builtin_object(self.name.removeprefix("builtin:"), config)
        return load_mesh(self.path, config)

    @property
    def stem(self) -> str:
        return self.name.removeprefix("builtin:") if self.path is None else self.path.stem

    @property
    def title(self) -> str:
        """What evaluate's and benchmark's tables, plots and recordings call the mesh: ``label`` or the stem."""
        return self.label or self.stem

    @property
    def recorded(self) -> str:
        """What shards, manifests and cards record as the mesh's source: its file name, or where
        another mesh of the job has the same stem (ShapeNet's ``model_normalized.obj``), its path
        under the folder given (``label``); ``builtin:NAME`` for a shape."""
        return self.label or self.name

    @property
    def slug(self) -> str:
        """The mesh in a shard's file name: the stem, or ``label`` without its suffix, '/' as '-'
        (``02691156-1a2b-models-model_normalized``)."""
        return str(Path(self.label).with_suffix("")).replace("/", "-") if self.label else self.stem


def with_labels(sources: list[MeshSource], root: Path) -> list[MeshSource]:
    """``sources`` with ``label`` set on each file whose stem another one has too: its path under
    ``root`` (posix, ``02691156/1a2b/models/model_normalized.obj``), so tables tell them apart."""
    stems = Counter(source.stem for source in sources)
    return [dataclasses.replace(source, label=Path(os.path.relpath(source.path, root)).as_posix())
            if source.path is not None and stems[source.stem] > 1 else source for source in sources]


def builtin_sources(config: MeshConfig = MeshConfig()) -> list[MeshSource]:
    """The built-in procedural shapes: the job's default when no meshes are given."""
    return [MeshSource(f"builtin:{name}", builtin_object(name, config).mesh_id) for name in BUILTIN_SHAPES]


def mesh_sources(where: Path) -> tuple[list[MeshSource], list[tuple[str, str]]]:
    """Sources from a folder (searched recursively), one mesh file, or a .txt list of files
    (one path per line, relative to the list; # starts a comment).

    Returns (sources, failures): files that cannot even be read are failures (name, reason).
    Files with the same stem are labelled with their path under the folder (or the list's folder).
    """
    where = Path(where)
    root = where.parent if where.is_file() else where
    if where.is_file() and where.suffix.lower() == ".txt":
        lines = [line.split("#", 1)[0].strip() for line in where.read_text().splitlines()]
        files = [where.parent / line for line in lines if line]
        if not files:
            raise MeshError(f"{where}: the list names no mesh files")
    elif where.is_file():
        files = [where]
    else:
        files = find_meshes(where)
    sources, failures = [], []
    for path in files:
        try:
            sources.append(MeshSource(path.name, sha256_file(path), path))
        except OSError as error:
            failures.append((str(path), f"cannot read the file: {error.strerror or error}"))
    return with_labels(sources, root), failures


def part_sources(manifest: str | Path, part: str, mesh_root: str | Path | None) -> tuple[list[MeshSource], dict]:
    """The meshes of ``part`` (train, val or test) of a published version's mesh split, each file
    found in or below ``mesh_root`` by its name and sha256 (``find_part_meshes``:
    ManifestError naming a missing or changed one), and what to record of the choice:
    {"manifest": {name, version, sha256 of the manifest's bytes, path, part, meshes (count)}}."""
    published = load_manifest(manifest)
    meshes = find_part_meshes(published, part, mesh_root)
    sources = with_labels([MeshSource(Path(mesh.source).name if mesh.path else mesh.source, mesh.mesh_id, mesh.path)
                           for mesh in meshes], Path(mesh_root or "."))
    record = {key: published.identity[key] for key in ("name", "version", "sha256", "path")}
    return sources, {"manifest": record | {"part": part, "meshes": len(sources)}}


@dataclass(frozen=True)
class PublishedMesh:
    """A mesh of a published version, found: ``source`` as the manifest records it (a file name
    or ``builtin:NAME``), ``mesh_id``, and ``path`` (None for a built-in shape)."""

    source: str
    mesh_id: str
    path: Path | None


def find_part_meshes(published: Published, part: str, mesh_root: str | Path | None) -> list[PublishedMesh]:
    """The meshes of ``part`` of the version's mesh split: every file is looked up in or below
    ``mesh_root`` by the source the manifest records (a file name, or a path its own path ends with)
    and taken only when its sha256 is the
    recorded one (a mesh id is the sha256 of its file); a built-in shape must give its recorded
    id. ManifestError, in one line naming the meshes, when one is missing or differs."""
    records = published.part_meshes(part)
    files = [record for record in records if not str(record["source"]).startswith("builtin:")]
    where = f"the {part} part of {published.label}"
    found: dict[str, list[Path]] = defaultdict(list)
    if files:
        if mesh_root is None:
            raise ManifestError(f"{where} names mesh files: pass --meshes ROOT, the folder they lie in or below "
                                "(e.g. ../shared/meshes)")
        root = Path(mesh_root)
        if not root.is_dir():
            raise ManifestError(f"--meshes {root}: no such folder; pass the folder the meshes of {where} lie in or "
                                "below (e.g. ../shared/meshes)")
        names = {Path(record["source"]).name for record in files}
        for path in sorted(root.rglob("*")):
            if path.name in names and path.is_file():
                found[path.name].append(path)
    meshes, missing, changed = [], [], []
    for record in records:
        source, mesh_id = str(record["source"]), str(record["id"])
        if source.startswith("builtin:"):
            name = source.removeprefix("builtin:")
            if name not in BUILTIN_SHAPES or builtin_object(name).mesh_id != mesh_id:
                changed.append(f"{source} (this nbvdata's shape is another)")
            meshes.append(PublishedMesh(source, mesh_id, None))
            continue
        # a file name, or a path under the generation's folder (``MeshSource.recorded``): the files that end so
        candidates = [path for path in found.get(Path(source).name, []) if path.as_posix().endswith(source)]
        match = next((path for path in candidates if sha256_file(path) == record["sha256"]), None)
        if match is None:
            (changed if candidates else missing).append(str(candidates[0]) if candidates else source)
        meshes.append(PublishedMesh(source, mesh_id, match))
    if missing:
        raise ManifestError(f"{some_names(missing)} of {where}: not found in or below {mesh_root}: pass --meshes the "
                            "folder that holds the published meshes")
    if changed:
        raise ManifestError(f"{some_names(changed)}: sha256 differs from the mesh {where} records (another object): "
                            "restore the published file, or pass --meshes the folder that holds it")
    return meshes


class SceneCache:
    """The scenes of the last ``size`` meshes asked for (None: of every mesh), each with its mesh
    and, for a noise-free sensor, its view cache: (mesh, scene, view cache) by (mesh source, data
    settings, threads). Everything in a scene is a function of the mesh, the data settings (all but
    ``generate``) and the seed, so taking it from here changes no byte. Not thread-safe: a view
    cache has scratch buffers."""

    def __init__(self, size: int | None):
        self.size = size
        self._entries: OrderedDict = OrderedDict()

    def get(self, source: MeshSource, config: SimConfig, threads: int = 0) -> tuple[ObjectMesh, Scene, ViewCache | None]:
        """The entry of ``source`` under ``config``: built here (``threads`` > 0 limits the ray
        casting threads), or the one kept."""
        key = (source, dataclasses.replace(config, generate=GenerateConfig()), threads)
        if key in self._entries:
            self._entries.move_to_end(key)
            return self._entries[key]
        obj = source.load(config.mesh)
        scene = Scene.build(obj, config, scene_rng(config.episode.seed, source.mesh_id), threads)
        entry = obj, scene, ViewCache(scene, config.state.points > 0) if config.sensor.noise_std == 0 else None
        if self.size is None or self.size > 0:
            self._entries[key] = entry
            while self.size is not None and len(self._entries) > self.size:
                self._entries.popitem(last=False)
        return entry

    def __len__(self) -> int:
        return len(self._entries)
