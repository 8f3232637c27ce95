import numpy as np
import pytest
import trimesh

from nbvdata.core.config import SensorConfig
from nbvdata.core.views import Pose
from nbvdata.simulation.sensor import NO_HIT, MeshScanner, camera_rays

SMALL = SensorConfig(width=40, height=30)


@pytest.fixture(scope="module")
def box_scanner():
    return MeshScanner(trimesh.creation.box((0.2, 0.2, 0.2)), SMALL)


def test_camera_rays_span_the_field_of_view():
    rays = camera_rays(SMALL)
    assert rays.shape == (40 * 30, 3)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1)
    half_h = np.arctan2(rays[:, 0], rays[:, 2])
    assert np.isclose(half_h.max(), 0.385, atol=0.77 / 40)
    assert (rays[:, 2] > 0).all()


def test_box_seen_from_plus_x_returns_its_plus_x_face(box_scanner):
    scan = box_scanner.scan(Pose.look_at([0.4, 0, 0]))
    assert scan.points.dtype == np.float32 and scan.points.shape == (1200, 3)
    hits = scan.hit_points
    assert 0 < len(hits) < 1200
    np.testing.assert_allclose(hits[:, 0], 0.1, atol=1e-6)
    far = np.linalg.norm(scan.points[~scan.hit] - scan.origin, axis=1)
    np.testing.assert_allclose(far, 2 * SMALL.far, rtol=1e-6)


def test_batched_scans_equal_single_scans(box_scanner):
    poses = [Pose.look_at(p) for p in ([0.4, 0, 0], [0, 0.3, 0.2], [0.1, -0.1, 0.35])]
    batched = box_scanner.scan_many(poses)
    for pose, scan in zip(poses, batched):
        single = box_scanner.scan(pose)
        np.testing.assert_array_equal(single.points, scan.points)
        np.testing.assert_array_equal(single.hit, scan.hit)


def test_noise_is_seeded_and_needs_a_generator():
    noisy = MeshScanner(trimesh.creation.box((0.2, 0.2, 0.2)), SensorConfig(width=40, height=30, noise_std=0.002))
    pose = Pose.look_at([0.4, 0, 0])
    a = noisy.scan(pose, np.random.default_rng(7))
    b = noisy.scan(pose, np.random.default_rng(7))
    np.testing.assert_array_equal(a.points, b.points)
    assert 0.0005 < np.std(a.hit_points[:, 0]) < 0.004
    with pytest.raises(ValueError, match="Generator"):
        noisy.scan(pose)
    exact = noisy.scan_many([pose], noiseless=True)[0]
    np.testing.assert_allclose(exact.hit_points[:, 0], 0.1, atol=1e-6)


def test_a_ray_that_hits_on_one_cpu_and_misses_on_another_moves_no_other_rays_noise():
    """Noise is drawn per pixel, hit or not: when Embree gives a few rays a miss (another CPU's
    answer at an outline), every other pixel keeps its noisy point, in the image and the cloud.
    (Drawn per hit, as before, every ray after a flipped one would take its neighbour's draw.)"""
    scanner = MeshScanner(trimesh.creation.box((0.2, 0.2, 0.2)), SensorConfig(width=40, height=30, noise_std=0.002))
    poses = [Pose.look_at([0.4, 0.05, 0.1]), Pose.look_at([-0.1, 0.3, 0.2])]
    before = scanner.scan_many(poses, np.random.default_rng(5))
    embree = scanner._triangles
    flipped = {}

    def other_cpu(rays):
        triangles = embree(rays).copy()
        hits = np.flatnonzero(triangles != NO_HIT)
        chosen = hits[[0, len(hits) // 3, len(hits) // 2]]  # early rays too, so that later ones would shift
        triangles[chosen] = NO_HIT
        flipped["count"] = len(chosen)
        return triangles

    scanner._triangles = other_cpu
    after = scanner.scan_many(poses, np.random.default_rng(5))
    scanner._triangles = embree
    changed = 0
    for a, b in zip(before, after):
        same = a.hit == b.hit
        changed += int(np.count_nonzero(~same))
        assert not (b.hit & ~a.hit).any()  # only hits became misses
        np.testing.assert_array_equal(a.points[same], b.points[same])
        kept = (a.hit & b.hit)[a.hit]  # a's cloud rows (its hits, pixel order) that b also hit
        np.testing.assert_array_equal(a.cloud[kept], b.cloud)
    assert changed == flipped["count"] == 3  # the flips are in the images (one call for both views)


def test_a_scan_without_its_cloud_is_the_same_scan_and_draws_the_same_noise():
    """``cloud=False`` skips the canonical triangles (and never builds the cells); the range
    image, the hits and the noise drawn after the scan are unchanged."""
    mesh = trimesh.creation.annulus(0.05, 0.1, 0.15)  # curved faces and shared edges
    poses = [Pose.look_at(p) for p in ([0.4, 0, 0], [0, 0.3, 0.2], [0.1, -0.1, 0.35])]
    for noise_std in (0.0, 0.002):
        config = SensorConfig(width=40, height=30, noise_std=noise_std)
        lean, full = MeshScanner(mesh, config), MeshScanner(mesh, config)
        rngs = np.random.default_rng(3), np.random.default_rng(3)
        without = lean.scan_many(poses, rngs[0], cloud=False)
        with_cloud = full.scan_many(poses, rngs[1])
        assert lean._cells is None and full._cells is not None
        for a, b in zip(without, with_cloud):
            np.testing.assert_array_equal(a.points, b.points)
            np.testing.assert_array_equal(a.hit, b.hit)
            assert a.cloud is None and b.cloud is not None and len(b.cloud) == b.hit.sum() > 0
            np.testing.assert_array_equal(a.cloud_points, a.hit_points)
            np.testing.assert_allclose(b.cloud, b.hit_points, atol=1e-5)
        assert rngs[0].random() == rngs[1].random()


def test_near_and_far_range_limit_returns():
    mesh = trimesh.creation.box((0.2, 0.2, 0.2))
    pose = Pose.look_at([0.4, 0, 0])
    assert not MeshScanner(mesh, SensorConfig(width=8, height=6, far=0.25)).scan(pose).hit.any()
    assert not MeshScanner(mesh, SensorConfig(width=8, height=6, near=0.35)).scan(pose).hit.any()


def test_casting_only_the_rays_near_the_box_changes_no_scan():
    """The bounded cast (default) against casting every ray: the same points and hits, from
    views all round, from inside the box, and for a flat mesh (a box of zero thickness)."""
    from nbvdata.core.config import ViewConfig
    from nbvdata.core.views import view_sphere
    from nbvdata.simulation.shapes import builtin_object

    config = SensorConfig(width=88, height=72, noise_std=0.001)
    flat = trimesh.Trimesh([[-0.05, -0.05, 0], [0.05, -0.05, 0], [0, 0.05, 0]], [[0, 1, 2]])
    poses = list(view_sphere(ViewConfig(count=40, radius=0.3, layout="sphere")))
    poses.append(Pose.look_at([0.01, 0.0, 0.005], target=[0.3, 0.1, 0.0]))  # inside the mug's box
    for mesh in (builtin_object("mug").mesh, builtin_object("table_lamp").mesh, flat):
        bounded, every = MeshScanner(mesh, config), MeshScanner(mesh, config, bounded=False)
        fast = bounded.scan_many(poses, np.random.default_rng(3))
        reference = every.scan_many(poses, np.random.default_rng(3))
        assert sum(scan.hit.sum() for scan in reference) > 1000
        for a, b in zip(fast, reference):
            np.testing.assert_array_equal(a.points, b.points)
            np.testing.assert_array_equal(a.hit, b.hit)
        exact = every.scan_many(poses, noiseless=True)
        for hit_points, scan in zip(bounded.iter_hit_points(poses), exact):  # the scene's path
            np.testing.assert_array_equal(hit_points, scan.hit_points)


def test_a_point_on_a_triangle_finds_it_in_its_cell():
    """Every triangle lies in the cells of all points within REACH of it: random points on the
    triangles of a mesh (pushed up to REACH/2 off them) find their triangle in their cell's list,
    and the lists are ascending."""
    from nbvdata.simulation.sensor import REACH, TriangleCells
    from nbvdata.simulation.shapes import builtin_object

    mesh = builtin_object("mug").mesh
    vertices, faces = np.asarray(mesh.vertices, dtype=np.float32), np.asarray(mesh.faces)
    cells = TriangleCells.build(vertices, faces)
    assert np.prod(cells.shape) > 100 and len(cells.members) >= len(faces)
    rng = np.random.default_rng(3)
    f = rng.integers(0, len(faces), 2000)
    weights = rng.dirichlet(np.ones(3), 2000)
    points = np.einsum("nk,nkd->nd", weights, vertices[faces[f]].astype(np.float64))
    points += rng.uniform(-REACH / 2 / np.sqrt(3), REACH / 2 / np.sqrt(3), points.shape)
    index = np.clip(np.floor((points - cells.low) / cells.size).astype(int), 0, cells.shape - 1)
    cell = (index[:, 0] * cells.shape[1] + index[:, 1]) * cells.shape[2] + index[:, 2]
    for triangle, c in zip(f, cell):
        members = cells.members[cells.start[c]:cells.start[c + 1]]
        assert triangle in members
        assert np.all(np.diff(members) > 0)


def test_the_cells_narrow_the_search_without_changing_the_answer():
    """The clouds' distances (canonical triangles, outlines passed through) with coarse and fine
    cells are the same; long slivers across the whole object make the grid coarser instead of
    filling every cell they cross."""
    from nbvdata.simulation.sensor import TriangleCells
    from nbvdata.simulation.shapes import builtin_object

    mesh = builtin_object("mug").mesh
    scanner = MeshScanner(mesh, SensorConfig(width=176, height=144))
    poses = [Pose.look_at((0.3, 0.2, 0.2)), Pose.look_at((0.0, 0.4, 0.05))]
    positions, rotations = np.array([p.position for p in poses]), np.array([p.rotation for p in poses])
    rays, cast, triangles, t_cast = scanner._distances(positions, rotations)
    answers = []
    for per_cell in (0.5, 4.0, 1e9):  # 1e9: one cell holds every triangle
        scanner._cells = TriangleCells.build(scanner._vertices, scanner._faces, per_cell)
        answers.append(scanner._cloud_distances(rays, cast, triangles, t_cast.copy()))
    assert np.isfinite(answers[0]).sum() > 5000
    assert np.count_nonzero(answers[0] != t_cast) > 0  # some rays met another triangle's plane or passed
    np.testing.assert_array_equal(answers[0], answers[1])
    np.testing.assert_array_equal(answers[0], answers[2])
    rng = np.random.default_rng(1)
    ends = rng.uniform(-0.1, 0.1, (3000, 2, 3)).astype(np.float32)  # 3,000 slivers from corner to corner
    vertices = np.concatenate([ends.reshape(-1, 3), ends[:, 0] + np.float32(1e-4)])
    faces = np.stack([np.arange(3000) * 2, np.arange(3000) * 2 + 1, 6000 + np.arange(3000)], axis=1)
    cells = TriangleCells.build(vertices, faces)
    assert len(cells.members) <= max(16 * 3000, 2**20)


def test_a_ray_at_an_edge_gets_the_same_cloud_point_from_either_triangle():
    """Rays aimed at a crease between two triangles, each reported as hitting one and then the
    other (what two CPUs' Embree kernels may do): the distance to the reported triangle's plane
    differs between the two, the canonical distance does not."""
    from nbvdata.simulation.sensor import TriangleCells, _canonical_distances, plane_distances

    vertices = np.array([[0, -0.05, 0], [0, 0.05, 0], [-0.04, 0, -0.03], [0.05, 0.01, -0.01]], dtype=np.float32)
    faces = np.array([[0, 1, 2], [1, 0, 3]], dtype=np.uint32)  # a crease along the y axis
    rng = np.random.default_rng(0)
    targets = np.stack([np.zeros(200), rng.uniform(-0.04, 0.04, 200), np.zeros(200)], axis=1)
    targets[:, 0] += rng.uniform(-2e-7, 2e-7, 200)  # within Embree's float32 doubt of the edge
    origins = np.array([0.1, 0.05, 0.4]) + rng.uniform(-0.02, 0.02, (200, 3))
    directions = (targets - origins) / np.linalg.norm(targets - origins, axis=1, keepdims=True)
    rays = np.concatenate([origins, directions], axis=1).astype(np.float32)
    cast = np.arange(200)
    cells = TriangleCells.build(vertices, faces)
    answers = {}
    for f in (0, 1):
        triangle = np.full(200, f, dtype=np.uint32)
        t_cast, t_cloud, canon = np.empty(200), np.empty(200), np.empty(200, dtype=np.int64)
        plane_distances(rays, cast, triangle, vertices, faces, t_cast)
        _canonical_distances(rays, cast, triangle, t_cast, vertices, faces, *cells, t_cloud, canon, np.empty(200))
        answers[f] = t_cast, t_cloud
    assert np.all(np.isfinite(answers[0][1]))
    assert np.count_nonzero(answers[0][0] != answers[1][0]) > 100  # the reported planes disagree
    assert np.array_equal(answers[0][1], answers[1][1])  # the canonical triangle does not
    np.testing.assert_allclose(answers[0][1], answers[0][0], atol=1e-6)


def test_a_sliver_claims_no_hit_behind_its_sharp_corner():
    """A 1-degree sliver (triangle 0) with its sharp corner at the origin, 7 um above a plane
    (triangle 1): a ray down through x = -0.1 mm meets the plane. Behind the corner the plane point
    of the sliver lies within 3.8 um of both long edges' *lines* (0.1 mm x sin 0.5 deg = 0.87 um),
    though 0.1 mm from the sliver: it must not be a candidate, or the cloud point lands 7 um off
    the surface (up to 0.4 mm for such a sliver: the teddy bear of issue 50)."""
    from nbvdata.simulation.sensor import EDGE_TOLERANCE, TriangleCells, _canonical_distances, plane_distances

    half = 0.05 * np.tan(np.radians(0.5))
    vertices = np.array([[0, 0, 7e-6], [0.05, -half, 7e-6], [0.05, half, 7e-6],
                         [-0.02, -0.02, 0], [0.02, -0.02, 0], [0, 0.03, 0]], dtype=np.float32)
    faces = np.array([[0, 1, 2], [3, 4, 5]], dtype=np.uint32)
    rays = np.array([[-1e-4, 0, 0.4, 0, 0, -1]], dtype=np.float32)
    cast, reported = np.array([0]), np.array([1], dtype=np.uint32)  # Embree: the plane below
    t_cast, t_cloud, canon = np.empty(1), np.empty(1), np.empty(1, dtype=np.int64)
    plane_distances(rays, cast, reported, vertices, faces, t_cast)
    _canonical_distances(rays, cast, reported, t_cast, vertices, faces, *TriangleCells.build(vertices, faces),
                         t_cloud, canon, np.empty(1))
    assert canon[0] == 1 and t_cloud[0] == t_cast[0] == np.float64(np.float32(0.4))
    assert EDGE_TOLERANCE < 7e-6 < 2 * EDGE_TOLERANCE  # the sliver is within the depth window, beyond the bound


def test_scan_clouds_do_not_depend_on_which_triangle_embree_reports():
    """A whole scanner whose Embree casts every ray a few ulps off (another CPU's float32 doubt),
    on a mesh with every kind of tie: shared edges (a mug), duplicated faces (a copy of its faces,
    wound the other way), parts that cross (a box through its wall) and outlines (its rim, its
    silhouettes, the box's edges). Many rays then report another triangle, some hit where they
    missed or the reverse, and their hit points change; the clouds do not, and nearly every cloud
    point lies within micrometres of its hit."""

    from nbvdata.core.config import ViewConfig
    from nbvdata.core.views import view_sphere
    from nbvdata.simulation.shapes import builtin_object

    mug = builtin_object("mug").mesh
    box = trimesh.creation.box(extents=(0.02, 0.2, 0.03))
    box.apply_translation((float(mug.bounds[1, 0]), 0.0, 0.0))  # through the mug's wall
    mesh = trimesh.util.concatenate([mug, trimesh.Trimesh(mug.vertices, mug.faces[:, ::-1], process=False), box])
    scanner = MeshScanner(mesh, SensorConfig(width=176, height=144))
    poses = list(view_sphere(ViewConfig(count=48, radius=0.4)))
    embree = scanner._triangles
    rng = np.random.default_rng(0)
    moved, flipped = [], []

    def other_cpu(rays):
        nudged = rays.copy()
        for _ in range(6):
            step = rng.integers(-1, 2, size=rays.shape)
            nudged = np.where(step > 0, np.nextafter(nudged, np.float32(np.inf)),
                              np.where(step < 0, np.nextafter(nudged, np.float32(-np.inf)), nudged))
        triangles, others = embree(rays), embree(nudged)
        moved.append(int(np.count_nonzero(triangles != others)))
        flipped.append(int(np.count_nonzero((triangles == NO_HIT) != (others == NO_HIT))))
        return others

    positions = np.array([p.position for p in poses])
    rotations = np.array([p.rotation for p in poses])
    before = scanner.scan_many(poses)
    rays, cast, triangles, t_cast = scanner._distances(positions, rotations)
    scanner._triangles = other_cpu
    after = scanner.scan_many(poses)
    _, _, _, other_t_cast = scanner._distances(positions, rotations)
    assert sum(moved) > 1000 and sum(flipped) > 0  # ties, and outlines grazed
    assert np.count_nonzero(t_cast != other_t_cast) > 100  # the reported planes' distances differ
    scanner._triangles = embree
    t_cloud = scanner._cloud_distances(rays, cast, triangles, t_cast)
    hit = np.isfinite(t_cast)
    passed = hit & ~(np.abs(t_cloud - np.where(hit, t_cast, 0.0)) <= 1e-5)
    assert 0 < np.count_nonzero(passed) < 1e-3 * hit.sum()  # outlines passed through: rare
    for a, b in zip(before, after):
        np.testing.assert_array_equal(a.cloud, b.cloud)


def test_a_ray_that_grazes_an_outline_gets_the_same_cloud_point_whether_it_hits_or_not():
    """Rays within 2e-7 m of a box's silhouette edges, in front of a wall: reported as hitting the
    box (one CPU) or as passing beside it to the wall (another), the canonical triangle alone
    keeps two answers; passing the outline through gives both the wall."""
    from nbvdata.simulation.sensor import _canonical_distances, plane_distances

    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    wall = trimesh.creation.box(extents=(0.02, 0.6, 0.6))
    wall.apply_translation((-0.3, 0.0, 0.0))
    scanner = MeshScanner(trimesh.util.concatenate([box, wall]), SMALL)
    rng = np.random.default_rng(2)
    origin = np.array([0.4, -0.12, 0.03])
    n = 400
    edge_z = rng.uniform(-0.045, 0.045, n)
    corner = np.stack([np.full(n, 0.05), np.full(n, 0.05), edge_z], axis=1)  # the edge x = y = 0.05
    directions = corner - origin
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    across = np.cross(directions, [0.0, 0.0, 1.0])  # across the edge, seen from the origin
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    across *= np.sign(across[:, 1:2])  # towards +y: out of the box's silhouette

    def rays_to(targets):
        aims = targets - origin
        aims /= np.linalg.norm(aims, axis=1, keepdims=True)
        return np.concatenate([np.tile(origin, (n, 1)), aims], axis=1).astype(np.float32)

    rays = rays_to(corner + rng.uniform(-2e-7, 2e-7, (n, 1)) * across)
    cast = np.arange(n)
    answers = {}
    for side, shift in (("box", -1e-6), ("wall", 1e-6)):  # what a ray 1 um to either side meets
        triangles = scanner._triangles(rays_to(corner + shift * across))
        t_cast, t_canonical = np.empty(n), np.empty(n)
        plane_distances(rays, cast, triangles, scanner._vertices, scanner._faces, t_cast)
        _canonical_distances(rays, cast, triangles, t_cast, scanner._vertices, scanner._faces, *scanner.cells,
                             t_canonical, np.empty(n, dtype=np.int64), np.empty(n))
        answers[side] = t_canonical, scanner._cloud_distances(rays, cast, triangles, t_cast)
    box_t, wall_t = answers["box"][0], answers["wall"][0]
    assert np.all(wall_t - box_t > 0.2)  # the canonical triangles: one ray, two answers
    np.testing.assert_array_equal(answers["box"][1], answers["wall"][1])
    np.testing.assert_array_equal(answers["box"][1], wall_t)  # passed through, to the wall
