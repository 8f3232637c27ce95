"""Load, validate and normalise object meshes into the reconstruction frame.

The reconstruction frame has the object's bounding-box centre at the origin, +z up, and the
largest bounding-box side equal to ``MeshConfig.object_size`` metres, so every object fits the
occupancy grid's cube whatever the units of its file. A mesh's id is the sha256 of its file
bytes, stable across machines and renames.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from nbvdata.config import MeshConfig

SUPPORTED_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")



class MeshError(ValueError):
    """A mesh file that cannot be used; the message names the file and the reason."""


@dataclass(frozen=True)
class ObjectMesh:
    """A normalised object, ready for scanning.

    mesh : trimesh.Trimesh in the reconstruction frame (metres, centred, +z up)
    mesh_id : sha256 hex digest of the source bytes
    source : file name (or built-in shape name) it came from
    scale : factor applied to the file's coordinates
    """

    mesh: trimesh.Trimesh
    mesh_id: str
    source: str
    scale: float


def sha256_file(path: str | Path) -> str:
    """Hex sha256 of a file's bytes, read in chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def find_meshes(folder: str | Path) -> list[Path]:
    """Mesh files (supported suffixes) directly in or below ``folder``, sorted by path."""
    folder = Path(folder)
    if not folder.is_dir():
        raise MeshError(f"{folder}: not a folder; pass the folder that holds the mesh files")
    files = sorted(p for p in folder.rglob("*") if p.is_file() and p.suffix.lower() in SUPPORTED_SUFFIXES)
    if not files:
        raise MeshError(f"{folder}: no mesh files ({', '.join(SUPPORTED_SUFFIXES)}) found")
    return files


def load_mesh(path: str | Path, config: MeshConfig = MeshConfig()) -> ObjectMesh:
    """Read a mesh file, merge its bodies and scene nodes into one mesh, validate, normalise.

    Raises MeshError naming the file for: an unsupported format, an unreadable file, no
    faces, non-finite vertices, or zero extent.
    """
    path = Path(path)
    if path.suffix.lower() not in SUPPORTED_SUFFIXES:
        raise MeshError(f"{path}: unsupported format '{path.suffix}'; use one of {', '.join(SUPPORTED_SUFFIXES)}")
    if not path.is_file():
        raise MeshError(f"{path}: no such file")
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as error:  # trimesh raises many kinds for damaged files
        raise MeshError(f"{path}: unreadable ({type(error).__name__}: {str(error)[:120]})") from None
    mesh, scale = normalise(_as_single_mesh(loaded, path), config, path)
    return ObjectMesh(mesh=mesh, mesh_id=sha256_file(path), source=path.name, scale=scale)


def _as_single_mesh(loaded: object, path: Path) -> trimesh.Trimesh:
    if isinstance(loaded, trimesh.Scene):  # force="mesh" already concatenates; guard the rest
        geometries = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)]
        loaded = trimesh.util.concatenate(geometries) if geometries else None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshError(f"{path}: the file holds no triangle faces (a point cloud or empty file?)")
    return loaded


def normalise(mesh: trimesh.Trimesh, config: MeshConfig, name: str | Path = "mesh") -> tuple[trimesh.Trimesh, float]:
    """Copy of ``mesh`` turned +z up, centred on its bounding box, largest side = object_size,
    and the scale factor applied.

    Only vertices used by a face count, so stray points in a file do not shift the object.
    """
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if not np.isfinite(vertices[np.unique(faces)]).all():
        raise MeshError(f"{name}: vertices with NaN or infinite coordinates; repair or re-export the mesh")
    used, faces = np.unique(faces, return_inverse=True)
    vertices = vertices[used]
    faces = faces.reshape(-1, 3)
    if config.up_axis == "y":
        # a +90 degree turn about x maps +y onto +z: (x, y, z) -> (x, -z, y), exactly
        vertices = np.stack([vertices[:, 0], -vertices[:, 2], vertices[:, 1]], axis=1)
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    extent = float((high - low).max())
    if not extent > 0:
        raise MeshError(f"{name}: zero extent (all vertices coincide); the file holds no usable shape")
    scale = config.object_size / extent
    vertices = (vertices - (low + high) / 2) * scale
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False), scale
