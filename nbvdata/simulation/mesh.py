"""Load, validate and normalise object meshes into the reconstruction frame.

The reconstruction frame has the object's bounding-box centre at the origin, +z up, and the
largest bounding-box side equal to ``MeshConfig.object_size`` metres, so every object fits the
occupancy grid's cube whatever the units of its file. A mesh's id is the sha256 of its file
bytes, stable across machines and renames.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from nbvdata.core.config import MeshConfig
from nbvdata.core.errors import UserError
from nbvdata.core.files import sha256_file

SUPPORTED_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")



class MeshError(UserError):
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


def find_meshes(folder: str | Path) -> list[Path]:
    """Mesh files (supported suffixes) directly in or below ``folder``, sorted by path."""
    folder = Path(folder)
    if not folder.exists():
        raise MeshError(f"{folder}: no such file or folder; pass a folder of mesh files, one mesh file "
                        f"({', '.join(SUPPORTED_SUFFIXES)}) or a .txt list of mesh files")
    if not folder.is_dir():
        raise MeshError(f"{folder}: not a folder; pass the folder that holds the mesh files")
    files = sorted(p for p in folder.rglob("*") if p.is_file() and p.suffix.lower() in SUPPORTED_SUFFIXES)
    if not files:
        raise MeshError(f"{folder}: no mesh files ({', '.join(SUPPORTED_SUFFIXES)}) found")
    return files


def load_mesh(path: str | Path, config: MeshConfig = MeshConfig()) -> ObjectMesh:
    """Read a mesh file, merge its bodies and scene nodes into one mesh, validate, normalise.

    Raises MeshError naming the file for: an unsupported format, content of another format
    (``check_content``), an unreadable file, no faces, non-finite vertices, or zero extent.
    """
    path = Path(path)
    if path.suffix.lower() not in SUPPORTED_SUFFIXES:
        raise MeshError(f"{path}: unsupported format '{path.suffix}'; use one of {', '.join(SUPPORTED_SUFFIXES)}")
    if not path.is_file():
        raise MeshError(f"{path}: no such file")
    check_content(path)
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except FileNotFoundError as error:  # a .gltf's .bin or texture
        raise MeshError(f"{path}: refers to {Path(error.filename or str(error)).name}, which is missing; "
                        "copy the file with everything it refers to") from None
    except Exception as error:  # trimesh raises many kinds for damaged files
        raise MeshError(f"{path}: unreadable as {_FORMATS[path.suffix.lower()]} ({type(error).__name__}: "
                        f"{str(error)[:120]}); the file may be cut off or damaged: re-export it") from None
    mesh, scale = normalise(_as_single_mesh(loaded, path), config, path)
    return ObjectMesh(mesh=mesh, mesh_id=sha256_file(path), source=path.name, scale=scale)


# What each suffix's format is called, and how many leading bytes identify a file's format.
_FORMATS = {".obj": "OBJ", ".ply": "PLY", ".off": "OFF", ".stl": "STL", ".glb": "GLB (binary glTF)",
            ".gltf": "glTF (JSON)"}
_HEAD_BYTES = 1 << 16


def check_content(path: Path) -> None:
    """Raise MeshError when the bytes of ``path`` cannot be a file of its suffix's format (an empty
    file, a text file renamed .ply, an OBJ saved as .stl, ...), saying why and, when the bytes are
    another mesh format, which one. Only headers are checked; a file that passes may still be damaged.
    """
    size = path.stat().st_size
    if size == 0:
        raise MeshError(f"{path}: empty file (0 bytes); export or copy the mesh again")
    with open(path, "rb") as handle:
        head = handle.read(_HEAD_BYTES)
    suffix = path.suffix.lower()
    problem = _format_problem(suffix, head, size)
    if problem is None:
        return
    actual = _sniff(head, size)
    if actual is not None and actual != suffix:
        hint = f"its content is {_FORMATS[actual]}: rename it to {path.stem}{actual}"
    elif actual == suffix:
        hint = "the file is cut off or damaged: export the mesh again"
    else:
        start = head.splitlines()[0][:40].decode("utf-8", "replace").strip()
        kind = "binary data" if b"\0" in head else f"text starting {start!r}"
        hint = f"its content ({kind}) does not match the {suffix} extension: export the mesh again"
    raise MeshError(f"{path}: not a valid {_FORMATS[suffix]} file: {problem}; {hint}")


def _first_line(head: bytes) -> bytes:
    """The first line that is neither blank nor a # comment, stripped."""
    for line in head.splitlines():
        if line.strip() and not line.lstrip().startswith(b"#"):
            return line.strip()
    return b""


def _is_off(head: bytes) -> bool:
    """Whether the first line starts with OFF (or COFF, NOFF, ...)."""
    words = _first_line(head).split()
    return bool(words) and words[0].upper().endswith(b"OFF")


def _stl_binary_size(head: bytes) -> int | None:
    """The size a binary STL with this header must have (84 + 50 per triangle), if it has a header."""
    return 84 + 50 * int.from_bytes(head[80:84], "little") if len(head) >= 84 else None


def _format_problem(suffix: str, head: bytes, size: int) -> str | None:
    """Why ``head`` (a file's first bytes, ``size`` in all) cannot be ``suffix``'s format, or None."""
    text = b"\0" not in head
    if suffix == ".ply":
        if head.splitlines()[0].strip().lower() != b"ply":
            return "no 'ply' header line"
        if b"end_header" not in head:
            return "its header has no end_header line"
    elif suffix == ".glb" and not head.startswith(b"glTF"):
        return "no 'glTF' magic bytes at its start"
    elif suffix == ".gltf" and not (text and head.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"{")):
        return "not JSON text"
    elif suffix == ".off" and not (text and _is_off(head)):
        return "no 'OFF' header line"
    elif suffix == ".stl" and _stl_binary_size(head) != size and not head.lstrip().lower().startswith(b"solid"):
        binary = ("shorter than the 84-byte header" if size < 84 else
                  f"{size} bytes do not fit the triangle count in its 84-byte header")
        return f"neither ASCII (no 'solid' line) nor binary ({binary})"
    elif suffix == ".obj":
        if not text:
            return "binary data, not OBJ text"
        if size <= len(head) and not re.search(rb"^\s*v\s", head, re.MULTILINE):
            return "no vertex lines ('v x y z')"
    return None


def _sniff(head: bytes, size: int) -> str | None:
    """The mesh format whose signature ``head`` carries, as a suffix, or None."""
    if head.splitlines()[0].strip().lower() == b"ply":
        return ".ply"
    if head.startswith(b"glTF"):
        return ".glb"
    if _stl_binary_size(head) == size or (head.lstrip().lower().startswith(b"solid") and b"facet" in head):
        return ".stl"
    if b"\0" in head:
        return None
    if _is_off(head):
        return ".off"
    if head.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"{") and b'"asset"' in head:
        return ".gltf"
    if re.search(rb"^\s*v\s", head, re.MULTILINE) and re.search(rb"^\s*f\s", head, re.MULTILINE):
        return ".obj"
    return None


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
