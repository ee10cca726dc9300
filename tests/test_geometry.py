import numpy as np
import pytest

from proctex.geometry.align import icp_to_surface, rotation_angle, umeyama, apply
from proctex.geometry.parts import segment
from proctex.geometry.shape import Shape, split_by_face_parts
from proctex.geometry.surface import SurfaceIndex, closest_point_bruteforce, closest_point_on_triangles, sample_surface, triangle_areas
from proctex.models import get_model

from .meshes import cube


def random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def test_closest_point_on_triangle_regions():
    a, b, c = np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]]), np.array([[0.0, 1, 0]])
    cases = {
        (0.2, 0.2, 1.0): (0.2, 0.2, 0.0),  # face
        (-1.0, -1.0, 0.0): (0.0, 0.0, 0.0),  # vertex a
        (0.5, -1.0, 0.0): (0.5, 0.0, 0.0),  # edge ab
        (1.0, 1.0, 0.0): (0.5, 0.5, 0.0),  # edge bc
        (3.0, -0.5, 0.0): (1.0, 0.0, 0.0),  # vertex b
    }
    for q, want in cases.items():
        cp, bary = closest_point_on_triangles(np.array([q]), a, b, c)
        np.testing.assert_allclose(cp[0], want, atol=1e-12)
        np.testing.assert_allclose(bary.sum(), 1.0)


def test_degenerate_triangle():
    a = np.array([[0.0, 0, 0]])
    cp, _ = closest_point_on_triangles(np.array([[0.5, 1.0, 0.0]]), a, np.array([[1.0, 0, 0]]), np.array([[2.0, 0, 0]]))
    np.testing.assert_allclose(cp[0], [0.5, 0, 0], atol=1e-12)
    cp, _ = closest_point_on_triangles(np.array([[0.5, 1.0, 0.0]]), a, a, a)
    np.testing.assert_allclose(cp[0], [0, 0, 0])


@pytest.mark.parametrize("backend", ["aabb", "proxies"])
@pytest.mark.parametrize("model,spread", [("sofa", 0.05), ("mug", 0.01), ("fork", 0.5)])
def test_surface_index_matches_bruteforce(model, spread, backend):
    shape = get_model(model).generate()
    rng = np.random.default_rng(0)
    pts, _, _ = sample_surface(shape.vertices, shape.faces, 150, seed=1)
    q = pts + rng.normal(0, spread, pts.shape)
    fast = SurfaceIndex(shape.vertices, shape.faces, backend=backend).query(q)
    slow = closest_point_bruteforce(shape.vertices, shape.faces, q)
    np.testing.assert_allclose(fast.distance, slow.distance, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(fast.points - q, axis=1), fast.distance, atol=1e-12)
    tri = shape.vertices[shape.faces[fast.faces]]
    np.testing.assert_allclose(np.einsum("ij,ijk->ik", fast.bary, tri), fast.points, atol=1e-12)


@pytest.mark.parametrize("backend", ["aabb", "proxies"])
def test_surface_index_on_degenerate_and_far_faces(backend):
    """Zero-area faces (a point, a segment), a face far away at 1e6, points off every edge: both
    backends give the brute-force distances and faces whose barycentrics rebuild the points."""
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1e6, 1e6, 0], [1e6, 1e6 + 1, 0], [1e6 + 1, 1e6, 0]], float)
    f = np.array([[0, 1, 3], [0, 1, 2], [2, 2, 2], [4, 5, 6]])
    q = np.array([[0.5, 1.0, 0.0], [3.0, 0.0, 0.0], [-1.0, -1.0, -1.0], [0.2, 0.2, 0.5], [1e6 + 0.1, 1e6 + 0.1, -3.0], [0.0, 0.0, 0.0]])
    fast = SurfaceIndex(v, f, backend=backend).query(q)
    slow = closest_point_bruteforce(v, f, q)
    np.testing.assert_allclose(fast.distance, slow.distance, atol=1e-9)
    np.testing.assert_allclose(np.einsum("ij,ijk->ik", fast.bary, v[f[fast.faces]]), fast.points, atol=1e-9)
    assert fast.faces[4] == 3 and fast.faces[1] in (1, 2)
    assert len(SurfaceIndex(v, f, backend=backend).query(np.zeros((0, 3))).faces) == 0


def test_surface_index_backends_and_bad_meshes(monkeypatch):
    import proctex.geometry.surface as surface

    shape = get_model("vase").generate()
    assert SurfaceIndex(shape.vertices, shape.faces).backend == "aabb"  # numba and libigl are dependencies
    q = shape.vertices[:50] + 0.01
    with_bvh = SurfaceIndex(shape.vertices, shape.faces).query(q)
    monkeypatch.setattr(surface, "_BVH", [None])  # where numba does not import: libigl's tree
    with_igl = SurfaceIndex(shape.vertices, shape.faces).query(q)
    np.testing.assert_allclose(with_igl.distance, with_bvh.distance, atol=1e-12)
    monkeypatch.setattr(surface, "_IGL", [None])  # and libigl neither (Blender's Python, say)
    index = SurfaceIndex(shape.vertices, shape.faces)
    assert index.backend == "proxies"
    np.testing.assert_allclose(index.query(q).distance, with_bvh.distance, atol=1e-12)
    with pytest.raises(ImportError, match="numba or libigl"):
        SurfaceIndex(shape.vertices, shape.faces, backend="aabb")
    monkeypatch.undo()
    with pytest.raises(ValueError, match="backend"):
        SurfaceIndex(shape.vertices, shape.faces, backend="bvh")
    with pytest.raises(ValueError, match="index"):
        SurfaceIndex(shape.vertices[:3], shape.faces)


def test_surface_index_rejects_bad_queries():
    shape = get_model("vase").generate()
    idx = SurfaceIndex(shape.vertices, shape.faces)
    with pytest.raises(ValueError, match="NaN"):
        idx.query(np.array([[np.nan, 0, 0]]))
    with pytest.raises(ValueError, match=r"\(q, 3\)"):
        idx.query(np.zeros((3, 2)))


def test_sampling_is_area_weighted_and_seeded():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [10, 0, 0], [12, 0, 0], [10, 2, 0]], float)
    f = np.array([[0, 1, 2], [3, 4, 5]])
    pts, fi, bary = sample_surface(v, f, 20000, seed=0)
    assert abs((fi == 1).mean() - 0.8) < 0.02  # areas 0.5 and 2
    np.testing.assert_array_equal(sample_surface(v, f, 10, seed=5)[0], sample_surface(v, f, 10, seed=5)[0])
    assert np.all(bary >= 0) and np.allclose(bary.sum(1), 1)
    np.testing.assert_allclose(triangle_areas(v, f), [0.5, 2.0])


@pytest.mark.parametrize("reflect", [False, True])
def test_umeyama_recovers_known_similarity(reflect):
    rng = np.random.default_rng(1)
    src = rng.normal(size=(50, 3))
    R = random_rotation(rng)
    if reflect:
        R = R @ np.diag([1, 1, -1])
    t, s = rng.normal(size=3), 1.7
    dst = s * src @ R.T + t
    R2, t2, s2 = umeyama(src, dst, scale=True, reflection=reflect)
    np.testing.assert_allclose(R2, R, atol=1e-10)
    np.testing.assert_allclose(t2, t, atol=1e-10)
    assert abs(s2 - s) < 1e-10
    R3, _, _ = umeyama(src, dst, scale=True, reflection=None)
    np.testing.assert_allclose(R3, R, atol=1e-10)


@pytest.mark.parametrize("reflect", [False, True])
def test_the_batched_umeyama_is_the_single_one_per_target(reflect):
    """Known similarities (one a reflection, one a degenerate flat target) recovered at once, and
    every target's answer the single :func:`umeyama`'s (the slow reference) on noisy targets."""
    from proctex.geometry.align import umeyama_batch

    rng = np.random.default_rng(2)
    src = rng.normal(size=(20, 3))
    Rs = [random_rotation(rng) for _ in range(5)]
    Rs[1] = Rs[1] @ np.diag([1, 1, -1])
    dst = np.stack([s * src @ R.T + t for R, s, t in zip(Rs, [0.5, 1.0, 2.0, 3.0, 1.3], rng.normal(size=(5, 3)))])
    dst[3, :, 2] = 0.0  # flat: a rank-2 covariance
    noisy = dst + rng.normal(0, 0.05, dst.shape)
    R, t, s = umeyama_batch(src, noisy, scale=True, reflection=reflect)
    for i in range(5):  # they differ by at most 4.4e-16 natively, 2.2e-16 on other kernels: 1e-9 leaves x2e6
        R1, t1, s1 = umeyama(src, noisy[i], scale=True, reflection=reflect)
        np.testing.assert_allclose(R[i], R1, atol=1e-9)
        np.testing.assert_allclose(t[i], t1, atol=1e-9)
        assert abs(s[i] - s1) < 1e-9
    R, t, s = umeyama_batch(src, dst[[0, 2]], scale=True)  # exact targets: their transforms
    np.testing.assert_allclose(R, [Rs[0], Rs[2]], atol=1e-10)
    np.testing.assert_allclose(s, [0.5, 2.0], atol=1e-10)
    with pytest.raises(ValueError, match="umeyama_batch"):
        umeyama_batch(src, dst[:, :5])


def test_affine_fit_recovers_a_known_affine_map():
    from proctex.geometry.align import affine_fit

    rng = np.random.default_rng(3)
    src = rng.normal(size=(30, 3))
    A0, t0 = rng.normal(size=(3, 3)), rng.normal(size=3)
    A, t, fitted = affine_fit(src, src @ A0.T + t0)  # off by 8.9e-16 on both kernel sets: 1e-10 leaves x1e5
    np.testing.assert_allclose(A, A0, atol=1e-10)
    np.testing.assert_allclose(t, t0, atol=1e-10)
    np.testing.assert_allclose(fitted, src @ A0.T + t0, atol=1e-10)
    with pytest.raises(ValueError, match="affine_fit"):
        affine_fit(src, src[:5])


def test_icp_recovers_small_rigid_motion():
    shape = get_model("chair").generate()  # no rotational symmetry
    idx = SurfaceIndex(shape.vertices, shape.faces)
    pts, _, _ = sample_surface(shape.vertices, shape.faces, 500, seed=3)
    angle = 0.15
    from proctex.geometry.primitives import rotation

    R = rotation([1, 2, 3], angle)
    t = np.array([0.02, -0.01, 0.015])
    moved = pts @ R.T + t
    res = icp_to_surface(moved, idx, max_iter=100)
    assert res.converged and res.error < 1e-6
    np.testing.assert_allclose(apply(moved, res.R, res.t), pts, atol=1e-5)
    assert abs(rotation_angle(res.R) - angle) < 1e-4


def test_point_icp_and_chamfer():
    from proctex.geometry.align import chamfer, icp_points
    from proctex.geometry.primitives import rotation

    shape = get_model("chair").generate()
    pts, _, _ = sample_surface(shape.vertices, shape.faces, 2000, seed=0)
    R = rotation([0, 0, 1], 0.1)
    moved = pts @ R.T + [0.01, 0.0, -0.01]
    assert chamfer(pts, pts) == 0.0
    before = chamfer(moved, pts)
    res = icp_points(moved, pts)
    assert res.converged and res.error < 1e-9  # the same points: exact recovery
    assert chamfer(apply(moved, res.R, res.t), pts) < 1e-9 < before


def test_query_facing_keeps_each_side_of_a_thin_wall():
    """A slab 0.02 thick: points of its top (some nearer the bottom), with the top's normal, land on
    the top (plain nearest takes the bottom for those); the same points with reversed normals as a
    whole (a mirrored part) still land on the top by majority, and on the bottom without it."""
    import trimesh

    from proctex.geometry.surface import SurfaceIndex

    slab = trimesh.creation.box((1.0, 1.0, 0.02))
    slab = slab.subdivide().subdivide()
    idx = SurfaceIndex(np.asarray(slab.vertices), np.asarray(slab.faces))
    rng = np.random.default_rng(0)
    z = np.r_[np.full(150, 0.006), np.full(50, -0.004)]  # points of the top; the last 50 nearer the bottom
    pts = np.column_stack([rng.uniform(-0.4, 0.4, 200), rng.uniform(-0.4, 0.4, 200), z])
    up = np.tile([0.0, 0.0, 1.0], (200, 1))
    assert (idx.query(pts).points[150:, 2] < 0).all()
    np.testing.assert_allclose(idx.query_facing(pts, up).points[:, 2], 0.01)
    np.testing.assert_allclose(idx.query_facing(pts, -up).points[:, 2], 0.01)  # reversed as a whole: majority
    np.testing.assert_allclose(idx.query_facing(pts, -up, majority=False).points[:, 2], -0.01)
    np.testing.assert_allclose(idx.query_facing(pts, np.zeros_like(pts)).points, idx.query(pts).points)
    with pytest.raises(ValueError, match="NaN"):
        idx.query_facing(pts, np.full_like(pts, np.nan))
    with pytest.raises(ValueError, match="both be"):
        idx.query_facing(pts, up[:3])
    # One candidate at first: those nearer the bottom widen the search until a facing face is found.
    np.testing.assert_allclose(idx.query_facing(pts, up, k=1).points[:, 2], 0.01)
    # ... but never beyond max_k: with one proxy allowed, the proxy search keeps each query's one
    # candidate (for some points of the top that is a bottom face: its centroid is nearer) ...
    proxies = SurfaceIndex(np.asarray(slab.vertices), np.asarray(slab.faces), backend="proxies")  # the AABB is always exact
    np.testing.assert_allclose(proxies.query_facing(pts, up, k=1, max_k=1).points, proxies.query(pts, exact=False, k=1).points)
    assert (proxies.query_facing(pts, up, k=1, max_k=1).points[:150, 2] < 0).any()
    # ... while the AABB tree gives every query its exact nearest face first: the top for the points
    # nearer the top, whatever max_k; the others keep their exact nearest when no candidate faces them.
    res = idx.query_facing(pts, up, k=1, max_k=1)
    np.testing.assert_allclose(res.points[:150, 2], 0.01)
    exact = idx.query(pts).points
    assert all(np.isclose(res.points[i, 2], 0.01) or np.allclose(res.points[i], exact[i]) for i in range(150, 200))


def test_query_facing_by_the_aabb_tree_is_the_nearest_facing_face_of_a_slow_search():
    """On a bumpy closed surface with queries off it and normals that sometimes oppose the nearest
    face, the AABB path answers each query whose exact nearest face faces it with that face (the
    exact nearest, checked against a search over every face), and the others as the proxy search
    does, keeping their exact nearest where it finds no facing face."""
    import trimesh

    from proctex.geometry.surface import SurfaceIndex, closest_point_bruteforce

    sphere = trimesh.creation.icosphere(subdivisions=2)
    rng = np.random.default_rng(3)
    v = np.asarray(sphere.vertices) * rng.uniform(0.8, 1.2, (len(sphere.vertices), 1))
    f = np.asarray(sphere.faces)
    aabb, proxies = SurfaceIndex(v, f), SurfaceIndex(v, f, backend="proxies")
    assert aabb.backend == "aabb"
    pts = rng.normal(size=(300, 3))
    pts = pts / np.linalg.norm(pts, axis=1, keepdims=True) * rng.uniform(0.7, 1.3, (300, 1))
    nrm = pts + rng.normal(size=(300, 3)) * 0.8  # mostly outward, some not
    got = aabb.query_facing(pts, nrm, k=4, majority=False, max_k=16)
    nearest = aabb.query(pts)  # the exact nearest (a tie at an edge or corner: the tree's own pick)
    # measured 1.4e-16 here and with numpy's AVX-512 kernels off; bound 1e-12 (passes under python -m tests.portable)
    np.testing.assert_allclose(nearest.distance, closest_point_bruteforce(v, f, pts).distance, atol=1e-12)
    faces_it = np.einsum("qd,qd->q", aabb.normals[nearest.faces], nrm) > 0
    assert 0.6 < faces_it.mean() < 1.0  # both kinds of query are there
    np.testing.assert_array_equal(got.faces[faces_it], nearest.faces[faces_it])
    np.testing.assert_allclose(got.points[faces_it], nearest.points[faces_it], atol=1e-12)  # measured 0 both ways
    others = proxies.query_facing(pts[~faces_it], nrm[~faces_it], k=4, majority=False, max_k=16)
    found = np.einsum("qd,qd->q", aabb.normals[others.faces], nrm[~faces_it]) > 0
    np.testing.assert_array_equal(got.faces[~faces_it][found], others.faces[found])
    np.testing.assert_array_equal(got.faces[~faces_it][~found], nearest.faces[~faces_it][~found])
    # an index that built its tree pickles without it (libigl's objects do not pickle) and answers the same
    import pickle

    again = pickle.loads(pickle.dumps(aabb))
    assert again._aabb is None and np.array_equal(again.query_facing(pts, nrm, k=4, majority=False, max_k=16).faces, got.faces)


def test_the_rows_not_facing_their_faces_are_the_same_compiled_or_in_arrays(monkeypatch):
    """``SurfaceIndex._not_facing`` (which queries the run time's UV lookup sends on to the proxy
    search) gives the same normals and rows from the compiled :func:`proctex.geometry.bvh.facing_dots`
    as from array operations (the dot products summed x, y, then z both ways: exact, margin none),
    with zero normals left out and the majority reversal: a pass that kept the zero normals, or took
    each face's own index as its normal's, would name other rows."""
    pytest.importorskip("numba")
    import trimesh

    from proctex.geometry import surface
    from proctex.geometry.surface import SurfaceIndex

    sphere = trimesh.creation.icosphere(subdivisions=2)
    idx = SurfaceIndex(np.asarray(sphere.vertices), np.asarray(sphere.faces), backend="aabb")
    rng = np.random.default_rng(5)
    faces = rng.integers(0, len(sphere.faces), 500)
    nrm = idx.normals[faces] + rng.normal(size=(500, 3)) * 1.2
    nrm[:30] = 0.0
    for majority, sign in ((False, 1.0), (True, 1.0), (True, -1.0)):
        compiled = idx._not_facing(faces, sign * nrm, majority)
        monkeypatch.setattr(surface, "_BVH", [None])
        arrays = idx._not_facing(faces, sign * nrm, majority)
        monkeypatch.undo()
        np.testing.assert_array_equal(compiled[0], arrays[0])
        np.testing.assert_array_equal(compiled[1], arrays[1])
        assert 30 < len(compiled[1]) < 470 and not np.isin(np.arange(30), compiled[1]).any()
    dots, zero = surface._bvh().facing_dots(idx.normals, faces, nrm)
    assert zero[:30].all() and not zero[30:].any()
    assert (dots[30:] > 0).any() and (dots[30:] < 0).any()
    assert not np.array_equal(np.flatnonzero((dots <= 0) & ~zero), np.flatnonzero(dots <= 0))  # the zero normals matter


def test_facing_faces_are_the_faces_query_facing_answers():
    """``facing_faces`` (the run time's UV lookup: faces without their closest points) names the
    faces ``query_facing`` answers, face for face, on both backends: a bumpy sphere with normals that
    sometimes oppose the nearest face, widening searches, a thin slab's majority reversal and its
    refusal, zero normals; an empty query gives no faces."""
    import trimesh

    from proctex.geometry.surface import SurfaceIndex

    sphere = trimesh.creation.icosphere(subdivisions=2)
    rng = np.random.default_rng(3)
    v = np.asarray(sphere.vertices) * rng.uniform(0.8, 1.2, (len(sphere.vertices), 1))
    f = np.asarray(sphere.faces)
    pts = rng.normal(size=(300, 3))
    pts = pts / np.linalg.norm(pts, axis=1, keepdims=True) * rng.uniform(0.7, 1.3, (300, 1))
    nrm = pts + rng.normal(size=(300, 3)) * 0.8
    nrm[:20] = 0.0  # no side
    slab = trimesh.creation.box((1.0, 1.0, 0.02)).subdivide().subdivide()
    sp = np.column_stack([rng.uniform(-0.4, 0.4, 200), rng.uniform(-0.4, 0.4, 200), np.r_[np.full(150, 0.006), np.full(50, -0.004)]])
    for backend in ("aabb", "proxies"):
        idx = SurfaceIndex(v, f, backend=backend)
        for args in ({"k": 4, "majority": False, "max_k": 16}, {"k": 1, "max_k": 1}, {}):
            np.testing.assert_array_equal(idx.facing_faces(pts, nrm, **args), idx.query_facing(pts, nrm, **args).faces)
        flat = SurfaceIndex(np.asarray(slab.vertices), np.asarray(slab.faces), backend=backend)
        up = np.tile([0.0, 0.0, 1.0], (200, 1))
        for n, majority in ((up, True), (-up, True), (-up, False)):
            np.testing.assert_array_equal(flat.facing_faces(sp, n, majority=majority), flat.query_facing(sp, n, majority=majority).faces)
        assert flat.facing_faces(sp[:0], up[:0]).shape == (0,)
        with pytest.raises(ValueError, match="NaN"):
            flat.facing_faces(sp, np.full_like(sp, np.nan))


def test_split_by_face_parts_cuts_a_connected_mesh_along_part_boundaries():
    """One cube (one connected part) whose faces are labelled by their normal's axis: no component
    spans two labels (opposite sides share a label but not a vertex, so they stay two parts),
    vertices are duplicated only where labels meet, and positions are unchanged."""
    v, f = cube()
    assert segment(Shape(v, f)).n_parts == 1
    normal_axis = np.argmax(np.abs(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])), axis=1)
    faces, source = split_by_face_parts(f, normal_axis * 10, len(v))  # labels need not be 0..k-1
    split = Shape(v[source], faces)
    seg = segment(split)
    assert seg.n_parts == 6 and split.n_vertices == 3 * 8  # each corner is in three axis classes
    assert np.allclose(split.vertices[split.faces], v[f])  # every triangle keeps its corners
    for part in range(6):
        assert len(set(normal_axis[seg.face_part == part])) == 1
    same, src = split_by_face_parts(f, np.zeros(len(f), dtype=int), len(v))
    assert np.array_equal(same, f) and np.array_equal(src, np.arange(8))
    unused, src = split_by_face_parts(f[:2], np.zeros(2, dtype=int), 8)
    assert np.array_equal(v[src][unused], v[f[:2]]) and len(src) == len(np.unique(f[:2]))
    with pytest.raises(ValueError, match="face_part"):
        split_by_face_parts(f, np.zeros(3), len(v))
    with pytest.raises(ValueError, match="face indices"):
        split_by_face_parts(f, np.zeros(len(f)), 4)


def test_row_products_are_the_bits_of_numpys_own_forms():
    """dot3 and cross3 (the GLB's normals and tangents, the UV lookup) equal ``(a * b).sum(1)`` and
    ``np.cross`` bit for bit, over magnitudes from 1e-12 to 1e12 and with signed zeros; a sum in
    another order (``a2 + a1 + a0``) differs on such rows: the comparison can fail."""
    from proctex.geometry.rowmath import cross3, dot3

    rng = np.random.default_rng(5)
    a = rng.normal(size=(20000, 3)) * 10.0 ** rng.uniform(-12, 12, (20000, 3))
    b = rng.normal(size=(20000, 3)) * 10.0 ** rng.uniform(-12, 12, (20000, 1))
    a[:5], b[5:10] = -0.0, 0.0
    np.testing.assert_array_equal(dot3(a, b), (a * b).sum(1))
    np.testing.assert_array_equal(cross3(a, b), np.cross(a, b))
    assert cross3(a, b).dtype == np.float64 and dot3(a, b).shape == (20000,)
    other = a[:, 2] * b[:, 2] + a[:, 1] * b[:, 1] + a[:, 0] * b[:, 0]
    assert (other != (a * b).sum(1)).any()


def test_bounds_are_the_column_minima_and_maxima():
    from proctex.geometry.rowmath import bounds

    rng = np.random.default_rng(5)
    for a in (rng.normal(size=(1000, 3)), rng.normal(size=(7, 2)).astype(np.float32), rng.integers(-9, 9, (50, 4)), np.array([[0.0, -0.0, 1e308]])):
        lo, hi = bounds(a)
        assert np.array_equal(lo, a.min(axis=0)) and np.array_equal(hi, a.max(axis=0)) and lo.dtype == a.dtype
