import csv
import hashlib

import numpy as np
import pytest
import trimesh
from conftest import MESHES, need

from nbvdata.core.config import MeshConfig
from nbvdata.simulation.mesh import MeshError, find_meshes, load_mesh


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
        "empty.obj": (b"", "empty file"),
        "garbage.stl": (b"\x00\x01garbage" * 3, "not a valid STL file: neither ASCII .* nor binary"),
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


@pytest.mark.parametrize("suffix, name", [(".ply", "PLY"), (".stl", "STL"), (".obj", "OBJ"), (".off", "OFF"),
                                          (".glb", "GLB"), (".gltf", "glTF")])
def test_a_text_file_with_a_mesh_suffix_is_named_as_such(tmp_path, suffix, name):
    path = tmp_path / f"notes{suffix}"
    path.write_text("reply to the ply export\nsecond line\n")  # "ply" in line 1 once fooled trimesh
    with pytest.raises(MeshError) as error:
        load_mesh(path)
    message = str(error.value)
    assert message.startswith(f"{path}: not a valid {name}") and f"does not match the {suffix} extension" in message
    assert "Error" not in message  # the reason, not a Python exception name


@pytest.mark.parametrize("saved, renamed", [(".obj", ".ply"), (".ply", ".obj"), (".stl", ".obj"), (".obj", ".stl"),
                                            (".glb", ".ply"), (".off", ".glb")])
def test_a_mesh_with_another_formats_suffix_names_its_real_format(tmp_path, saved, renamed):
    _write_box(tmp_path / f"box{saved}")
    (tmp_path / f"box{saved}").rename(tmp_path / f"box{renamed}")
    with pytest.raises(MeshError, match=rf"not a valid .* file: .*; its content is .*: rename it to box\{saved}$"):
        load_mesh(tmp_path / f"box{renamed}")


def test_cut_off_and_empty_files_say_so(tmp_path):
    for suffix in (".obj", ".ply", ".off", ".stl", ".glb", ".gltf"):
        (tmp_path / f"empty{suffix}").write_bytes(b"")
        with pytest.raises(MeshError, match=r"empty\.\w+: empty file \(0 bytes\)"):
            load_mesh(tmp_path / f"empty{suffix}")
    (tmp_path / "cut.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 8\n")
    with pytest.raises(MeshError, match="no end_header line; the file is cut off or damaged"):
        load_mesh(tmp_path / "cut.ply")


def test_ascii_variants_pass_the_content_check(tmp_path):
    box = trimesh.creation.box((2.0, 1.0, 0.5))
    box.export(tmp_path / "ascii.stl", file_type="stl_ascii")
    box.export(tmp_path / "ascii.ply", encoding="ascii")
    (tmp_path / "commented.off").write_text("# made by hand\n" + box.export(file_type="off"))
    for name in ("ascii.stl", "ascii.ply", "commented.off"):
        assert len(load_mesh(tmp_path / name).mesh.faces) == 12


def test_find_meshes_rejects_empty_folder(tmp_path):
    with pytest.raises(MeshError, match="no mesh files"):
        find_meshes(tmp_path)
    (tmp_path / "a.txt").write_text("")
    with pytest.raises(MeshError, match="a.txt: not a folder"):
        find_meshes(tmp_path / "a.txt")


def test_a_missing_path_says_what_is_accepted(tmp_path):
    with pytest.raises(MeshError) as error:
        find_meshes(tmp_path / "nope.obj")
    assert str(error.value) == (f"{tmp_path / 'nope.obj'}: no such file or folder; pass a folder of mesh files, "
                                "one mesh file (.obj, .ply, .off, .stl, .glb, .gltf) or a .txt list of mesh files")


def _listed_meshes() -> list:
    """train/ and test/ files as ../shared/meshes/MESHES.tsv lists them (columns split, file)."""
    with open(need(MESHES) / "MESHES.tsv", newline="", encoding="utf-8") as handle:
        return sorted(MESHES / row["split"] / row["file"] for row in csv.DictReader(handle, delimiter="\t"))


def test_every_shared_mesh_loads_or_gets_a_named_error():
    files = find_meshes(need(MESHES) / "train") + find_meshes(MESHES / "test")
    assert sorted(files) == _listed_meshes() and len(files) == 160
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


def test_the_extra_procedural_meshes_are_there_and_a_sample_loads():
    """extra/pybullet_random_urdfs: 1,000 small .obj; every 50th is loaded (all 1,000 take minutes)."""
    files = find_meshes(need(MESHES / "extra" / "pybullet_random_urdfs"))
    assert len(files) == 1000 and all(path.suffix == ".obj" for path in files)
    for path in files[::50]:
        obj = load_mesh(path)
        assert len(obj.mesh.faces) > 0
        np.testing.assert_allclose(np.ptp(obj.mesh.bounds, axis=0).max(), MeshConfig().object_size, rtol=1e-9)
