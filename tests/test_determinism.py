"""Same settings, same bytes on every x86-64 CPU.

A published manifest pins shards by sha256, so a user's regeneration must not depend on the
CPU's instruction set. The parts of a CPU that change arithmetic are simulated here, since a
test cannot choose its machine: OpenBLAS's kernel (``OPENBLAS_CORETYPE``), numpy's SIMD loops
(``NPY_DISABLE_CPU_FEATURES``), numba's target (``NUMBA_CPU_NAME``), and the last bits of the
ray caster's distances (Embree's kernels differ per instruction set, and the distance is
recomputed here from the triangle it reports). No test compares with bytes made elsewhere.
"""

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import trimesh

from nbvdata.core.config import SensorConfig
from nbvdata.core.files import sha256_file
from nbvdata.core.views import Pose, view_sphere
from nbvdata.simulation.sensor import MeshScanner
from nbvdata.simulation.shapes import BUILTIN_SHAPES, builtin_object

SMOKE = Path(__file__).resolve().parents[1] / "configs" / "smoke.yaml"
# Every numpy dispatch target above the x86-64-v2 baseline, OpenBLAS's SSE3 kernels (no AVX, no
# fused multiply-add) and numba's generic x86-64 target: arithmetic as on the oldest CPU.
OLD_CPU = {
    "NPY_DISABLE_CPU_FEATURES": "X86_V3 X86_V4 AVX512_ICL AVX512_SPR AVX512F AVX512CD AVX512_SKX AVX512_CLX "
                                "AVX512_CNL AVX2 FMA3",
    "OPENBLAS_CORETYPE": "Prescott",
    "NUMBA_CPU_NAME": "generic",
}


def _sha256s(folder: Path) -> dict[str, str]:
    return {path.name: sha256_file(path) for path in sorted(folder.glob("*.h5"))}


def _generate(out: Path, env: dict | None = None) -> None:
    command = [sys.executable, "-m", "nbvdata", "generate", "--out", str(out), "--config", str(SMOKE),
               "--workers", "1", "--set", "generate.runs_per_shard=1", "--runs-per-mesh", "6", "--no-progress"]
    result = subprocess.run(command, capture_output=True, text=True, env=env)
    assert result.returncode == 0, result.stderr


def test_shards_are_byte_identical_with_an_old_cpus_arithmetic(tmp_path):
    here, old = tmp_path / "here", tmp_path / "old"
    _generate(here)
    _generate(old, os.environ | OLD_CPU | {"NUMBA_CACHE_DIR": str(tmp_path / "jit")})
    assert len(_sha256s(here)) == 36 and _sha256s(here) == _sha256s(old)


_SHAPE_DIGESTS = """
import hashlib, json
from nbvdata.simulation.shapes import BUILTIN_SHAPES, builtin_object
print(json.dumps({name: [builtin_object(name).mesh_id,
                         hashlib.sha256(builtin_object(name).mesh.vertices.tobytes()).hexdigest()]
                  for name in BUILTIN_SHAPES}))
"""


def test_builtin_shapes_do_not_depend_on_the_blas_kernel():
    """trimesh rotates primitives with matrix products; OpenBLAS's kernels round them differently
    (the pill's vertices changed with OPENBLAS_CORETYPE=Prescott before the shapes were rounded)."""
    digests = {}
    for kernel in ("Prescott", "Sandybridge", "Haswell"):
        result = subprocess.run([sys.executable, "-c", _SHAPE_DIGESTS], capture_output=True, text=True,
                                env=os.environ | {"OPENBLAS_CORETYPE": kernel})
        assert result.returncode == 0, result.stderr
        digests[kernel] = json.loads(result.stdout)
    here = {name: [builtin_object(name).mesh_id, hashlib.sha256(builtin_object(name).mesh.vertices.tobytes())
                   .hexdigest()] for name in BUILTIN_SHAPES}
    assert all(d == here for d in digests.values())


class _PerturbedDistances:
    """A ray-casting scene whose distances are off by a few units in the last place, as another
    instruction set's kernels may compute them; the triangles hit are the true ones."""

    def __init__(self, scene, rng):
        self.scene, self.rng = scene, rng

    def cast_rays(self, rays, nthreads=0):
        from nbvdata.simulation._open3d import open3d as o3d

        result = self.scene.cast_rays(rays, nthreads=nthreads)
        t_hit = result["t_hit"].numpy()
        ulps = self.rng.integers(-3, 4, t_hit.shape).astype(np.int32)
        finite = np.isfinite(t_hit)
        t_hit[finite] = (t_hit[finite].view(np.int32) + ulps[finite]).view(np.float32)
        return {**result, "t_hit": o3d.core.Tensor(t_hit)}


def test_scans_do_not_depend_on_the_ray_casters_distance_arithmetic(rng):
    obj = builtin_object("mug")
    exact, perturbed = MeshScanner(obj.mesh), MeshScanner(obj.mesh)
    perturbed._scene = _PerturbedDistances(perturbed._scene, rng)
    views = view_sphere()
    for a, b in zip(exact.scan_many([views[v] for v in range(0, 500, 25)]),
                    perturbed.scan_many([views[v] for v in range(0, 500, 25)])):
        assert a.hit.sum() > 1000
        assert np.array_equal(a.points, b.points) and np.array_equal(a.hit, b.hit)


def test_a_face_seen_head_on_is_hit_exactly_on_its_plane():
    """The distance comes from the plane of the triangle hit, in float64: every point on the face
    x = 0.05 of a box seen from +x has x == float32(0.05) exactly (Embree's float32 distances
    scatter by a few units in the last place)."""
    box = trimesh.creation.box((0.1, 0.1, 0.1))
    scan = MeshScanner(box, SensorConfig()).scan(Pose.look_at(np.array([0.4, 0.0, 0.0])))
    assert scan.hit.sum() > 1000
    assert np.all(scan.hit_points[:, 0] == np.float32(0.05))
    assert np.all(np.abs(scan.hit_points[:, 1:]) <= 0.05 + 1e-7)


# ---------------------------------------------------------------------------------------------
# The same bytes whatever else the writing process did or does


def _smoke_units(*settings: str):
    from nbvdata.core.config import SimConfig, load_config
    from nbvdata.datasets.generate import plan_units
    from nbvdata.simulation.sources import builtin_sources

    config = load_config(SimConfig, SMOKE, ["generate.workers=1", *settings])
    return config, plan_units(builtin_sources(config.mesh)[:3], config)


def test_a_shard_is_the_same_bytes_while_something_else_holds_its_datasets(tmp_path, monkeypatch):
    """HDF5 places a chunk in the file when it leaves the dataset's cache, i.e. when the dataset is
    closed; a Dask worker's profiler samples the writing thread's frames and so keeps a dataset
    object alive a moment longer now and then (a killed worker's unit, redone elsewhere, came out
    in other bytes). Here every dataset object is held until the file is written."""
    import h5py

    from nbvdata.datasets.generate import run_unit

    config, units = _smoke_units("state.points=64")
    run_unit(units[0], config, tmp_path / "plain")
    held, create = [], h5py.Group.create_dataset

    def create_and_hold(group, *args, **kwargs):
        held.append(create(group, *args, **kwargs))
        return held[-1]

    monkeypatch.setattr(h5py.Group, "create_dataset", create_and_hold)
    run_unit(units[0], config, tmp_path / "held")
    assert len(held) >= 15
    held.clear()
    assert _sha256s(tmp_path / "plain") == _sha256s(tmp_path / "held")


_RUN_UNIT = """
import sys
from pathlib import Path
sys.path.insert(0, {tests!r})
from test_determinism import _smoke_units
from nbvdata.datasets.generate import run_unit
config, units = _smoke_units()
run_unit(units[{index}], config, Path({out!r}))
"""


def test_a_unit_redone_after_other_units_or_in_a_fresh_process_is_the_same_bytes(tmp_path):
    """What a lost cluster worker's unit goes through: done again by a worker that has already
    written other shards, or by a new process."""
    from nbvdata.datasets.generate import run_unit

    config, units = _smoke_units()
    for unit in units:
        run_unit(unit, config, tmp_path / "first")
    first = _sha256s(tmp_path / "first")
    assert len(first) == 3
    for unit in reversed(units):  # the same process, each unit after the others
        run_unit(unit, config, tmp_path / "again")
    fresh = tmp_path / "fresh"
    code = _RUN_UNIT.format(tests=str(Path(__file__).parent), index=1, out=str(fresh))
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert _sha256s(tmp_path / "again") == first
    assert _sha256s(fresh) == {units[1].shard_name: first[units[1].shard_name]}
