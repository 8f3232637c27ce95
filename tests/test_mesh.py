import hashlib

import numpy as np
import pytest
import trimesh

from conftest import MESHES, need
from nbvdata.config import MeshConfig
from nbvdata.mesh import MeshError, find_meshes, load_mesh


def _write_box(path, transform=None):
    box = trimesh.creation.box((2.0, 1.0, 0.5))
    if transform is not None:
        box.apply_transform(transform)
    box.export(path)
    return box


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".off", ".stl", ".glb"])
def test_formats_load_and_normalise(tmp_path, suffix):
    path = tmp_path / f"box{suffix}"
    _write_box(path, trimesh.transformations.translation_matrix([5, -3, 2]))
    obj = load_mesh(path, MeshConfig(object_size=0.2))
    bounds = obj.mesh.bounds
    np.testing.assert_allclose(bounds.mean(axis=0), 0, atol=1e-9)
    np.testing.assert_allclose(np.ptp(bounds, axis=0), [0.2, 0.1, 0.05], rtol=1e-6)
    assert obj.mesh_id == hashlib.sha256(path.read_bytes()).hexdigest()
    assert obj.source == path.name
    assert obj.scale == pytest.approx(0.1)


def test_scene_with_several_bodies_is_merged(tmp_path):
    scene = trimesh.Scene([trimesh.creation.box((1, 1, 1)),
                           trimesh.creation.icosphere().apply_translation([3, 0, 0])])
    path = tmp_path / "two.glb"
    scene.export(path)
    obj = load_mesh(path, MeshConfig(object_size=1.0))
    assert len(obj.mesh.faces) == 12 + len(trimesh.creation.icosphere().faces)
    np.testing.assert_allclose(np.ptp(obj.mesh.bounds, axis=0).max(), 1.0)


def test_y_up_files_are_turned_z_up(tmp_path):
    path = tmp_path / "tall_in_y.obj"
    trimesh.creation.box((0.1, 1.0, 0.2)).export(path)
    z_up = load_mesh(path, MeshConfig(object_size=1.0, up_axis="z"))
    y_up = load_mesh(path, MeshConfig(object_size=1.0, up_axis="y"))
    np.testing.assert_allclose(np.ptp(z_up.mesh.bounds, axis=0), [0.1, 1.0, 0.2], atol=1e-9)
    np.testing.assert_allclose(np.ptp(y_up.mesh.bounds, axis=0), [0.1, 0.2, 1.0], atol=1e-9)


def test_each_bad_file_gets_its_own_error(tmp_path):
    cases = {
        "unsupported.xyz": (b"1 2 3\n", "unsupported format"),
        "empty.obj": (b"", "no triangle faces"),
        "garbage.stl": (b"\x00\x01garbage" * 3, "unreadable|no triangle faces"),
        "points_only.obj": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no triangle faces"),
        "nan.obj": (b"v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite"),
        "collapsed.obj": (b"v 1 1 1\nv 1 1 1\nv 1 1 1\nf 1 2 3\n", "zero extent"),
    }
    for name, (content, message) in cases.items():
        path = tmp_path / name
        path.write_bytes(content)
        with pytest.raises(MeshError, match=message) as error:
            load_mesh(path)
        assert name in str(error.value), f"the error for {name} must name the file"
    with pytest.raises(MeshError, match="no such file"):
        load_mesh(tmp_path / "missing.obj")


def test_find_meshes_rejects_empty_folder(tmp_path):
    with pytest.raises(MeshError, match="no mesh files"):
        find_meshes(tmp_path)
    with pytest.raises(MeshError, match="not a folder"):
        find_meshes(tmp_path / "nope")


def test_every_shared_mesh_loads_or_gets_a_named_error():
    files = find_meshes(need(MESHES))
    assert len(files) == 160
    loaded = 0
    for path in files:
        try:
            obj = load_mesh(path)
        except MeshError as error:
            assert path.name in str(error)
            continue
        loaded += 1
        assert np.isfinite(obj.mesh.vertices).all() and len(obj.mesh.faces) > 0
        np.testing.assert_allclose(np.ptp(obj.mesh.bounds, axis=0).max(), MeshConfig().object_size, rtol=1e-9)
        np.testing.assert_allclose(obj.mesh.bounds.mean(axis=0), 0, atol=1e-9)
    assert loaded >= 150, f"only {loaded} of 160 shared meshes loaded"
