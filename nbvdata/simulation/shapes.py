"""Built-in procedural objects, so the commands work without any mesh files.

Each shape is a few trimesh primitives, deterministic, and normalised like a loaded file. Its
id is the sha256 of its name, vertices and faces.

Same vertices on every CPU: trimesh builds and rotates primitives with matrix products, which
numpy hands to OpenBLAS, whose kernels (chosen per CPU) may round the last bit differently. So
rotations here are written out element by element, and the finished shape's vertices are
rounded to a grid of 2^-24 of its unit (about 6e-8; 1.4e-8 m once scaled to 0.24 m), far below
anything the simulation resolves but far above a last-bit difference.
"""

from __future__ import annotations

import hashlib
from typing import Callable

import numpy as np
import trimesh
from trimesh.creation import box, capsule, cone, cylinder, icosphere, torus

from nbvdata.core.config import MeshConfig
from nbvdata.simulation.mesh import ObjectMesh, normalise

_QUANTUM = 2.0 ** -24


def _moved(mesh: trimesh.Trimesh, xyz: tuple[float, float, float]) -> trimesh.Trimesh:
    mesh.apply_translation(xyz)
    return mesh


def _rotated(mesh: trimesh.Trimesh, angle: float, axis: tuple[float, float, float]) -> trimesh.Trimesh:
    """``mesh`` rotated by ``angle`` about ``axis`` through the origin, without a BLAS call."""
    r = trimesh.transformations.rotation_matrix(angle, axis)[:3, :3]
    v = np.asarray(mesh.vertices, dtype=np.float64)
    rotated = np.stack([(v[:, 0] * r[a, 0] + v[:, 1] * r[a, 1]) + v[:, 2] * r[a, 2] for a in range(3)], axis=1)
    return trimesh.Trimesh(vertices=rotated, faces=mesh.faces, process=False)


def _mug() -> trimesh.Trimesh:
    handle = torus(major_radius=0.3, minor_radius=0.07, major_sections=32, minor_sections=12)
    handle = _rotated(handle, np.pi / 2, (1, 0, 0))
    return trimesh.util.concatenate([cylinder(radius=0.5, height=1.1, sections=48), _moved(handle, (0.5, 0, 0))])


def _table_lamp() -> trimesh.Trimesh:
    return trimesh.util.concatenate([
        cylinder(radius=0.35, height=0.08, sections=40),
        _moved(cylinder(radius=0.04, height=0.9, sections=16), (0, 0, 0.45)),
        _moved(cone(radius=0.3, height=0.35, sections=40), (0, 0, 0.75)),
    ])


def _step_block() -> trimesh.Trimesh:
    return trimesh.util.concatenate([
        box((1.0, 0.6, 0.3)), _moved(box((0.5, 0.6, 0.4)), (0.25, 0, 0.35)),
        _moved(box((0.25, 0.6, 0.3)), (-0.375, 0, 0.3)),
    ])


def _snowman() -> trimesh.Trimesh:
    return trimesh.util.concatenate([
        icosphere(subdivisions=3, radius=0.5), _moved(icosphere(subdivisions=3, radius=0.33), (0, 0, 0.7)),
        _moved(cone(radius=0.06, height=0.3, sections=16), (0, -0.3, 0.72)),
    ])


def _ring() -> trimesh.Trimesh:
    return torus(major_radius=0.5, minor_radius=0.15, major_sections=48, minor_sections=16)


def _pill() -> trimesh.Trimesh:
    pill = capsule(height=0.8, radius=0.25, count=(24, 24))
    return _rotated(pill, np.pi / 3, (0, 1, 0))


BUILTIN_SHAPES: dict[str, Callable[[], trimesh.Trimesh]] = {
    "mug": _mug,
    "table_lamp": _table_lamp,
    "step_block": _step_block,
    "snowman": _snowman,
    "ring": _ring,
    "pill": _pill,
}


def builtin_object(name: str, config: MeshConfig = MeshConfig()) -> ObjectMesh:
    """One built-in shape, normalised into the reconstruction frame."""
    if name not in BUILTIN_SHAPES:
        raise KeyError(f"unknown built-in shape {name!r}; known: {', '.join(BUILTIN_SHAPES)}")
    raw = BUILTIN_SHAPES[name]()
    raw = trimesh.Trimesh(vertices=np.round(raw.vertices / _QUANTUM) * _QUANTUM, faces=raw.faces, process=False)
    mesh, scale = normalise(raw, MeshConfig(object_size=config.object_size, up_axis="z"), name)
    digest = hashlib.sha256(name.encode())
    digest.update(np.ascontiguousarray(raw.vertices, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(raw.faces, dtype=np.int64).tobytes())
    return ObjectMesh(mesh=mesh, mesh_id=digest.hexdigest(), source=f"builtin:{name}", scale=scale)


def builtin_objects(config: MeshConfig = MeshConfig()) -> list[ObjectMesh]:
    """All built-in shapes, in a fixed order."""
    return [builtin_object(name, config) for name in BUILTIN_SHAPES]
