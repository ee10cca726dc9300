"""UV atlases, texel maps, seam padding, rasteriser and renderer."""

import os

import numpy as np
import pytest

from proctex._reference.raster import rasterise_reference
from proctex._reference.uv import texel_map_reference
from proctex.geometry import sweeps as S
from proctex.geometry.parts import analyse
from proctex.geometry.raster import rasterise
from proctex.geometry.surface import SurfaceIndex, triangle_areas
from proctex.models import get_model
from proctex.texture.render import (
    Camera,
    Tracer,
    bounding_sphere,
    canonical_cameras,
    default_up,
    embree_available,
    orbit_path,
    canonical_buffers,
    render_buffers,
    render_six_views,
    save_png,
    turntable,
    with_labels,
)
from proctex.geometry.shape import Shape
from proctex.texture.uv import fit_unit_square, pad_seams, planar_uv, sample_texture, shape_uv, source_uv, texel_map, unwrap, uv_to_pixel

from .meshes import cube


def cylinder(radius, height, segments):
    """Closed cylinder part (surface of revolution with poles)."""
    return S.revolve(np.full(4, radius), np.linspace(0, height, 4), n_theta=segments)


# ------------------------------------------------------------------------------------ rasteriser
@pytest.mark.parametrize("with_depth", [False, True])
def test_rasterise_matches_reference(with_depth):
    rng = np.random.default_rng(3)
    for _ in range(4):
        xy = rng.uniform(-4, 24, (10, 3, 2))
        depth = rng.uniform(1, 5, (10, 3)) if with_depth else None
        f1, b1 = rasterise(xy, 19, 17, depth)
        f2, b2 = rasterise_reference(xy, 19, 17, depth)
        # The same face everywhere, but where two faces meet at one depth (the two compute depth
        # with other sums, whose last bits follow the CPU: a tie may go either way there).
        other = f1 != f2
        if depth is not None and other.any():
            both = other & (f1 >= 0) & (f2 >= 0)
            z1 = (b1[both] * depth[f1[both]]).sum(-1)
            z2 = (b2[both] * depth[f2[both]]).sum(-1)
            assert both.sum() == other.sum() and np.allclose(z1, z2, rtol=1e-9, atol=0)
        else:
            assert not other.any()
        assert np.allclose(b1[~other], b2[~other], atol=1e-12)


def test_rasterise_square_covers_exact_pixels():
    # Square [2, 10] x [3, 7] in pixel units: pixel centres j+0.5 in [2, 10] -> j = 2..9, rows 3..6.
    xy = np.array([[[2, 3], [10, 3], [10, 7]], [[2, 3], [10, 7], [2, 7]]], dtype=float)
    face, bary = rasterise(xy + 1e-7, 12, 12)  # nudge off the pixel-centre grid lines
    assert (face >= 0).sum() == 8 * 4
    assert np.allclose(bary[face >= 0].sum(axis=1), 1)


def test_rasterise_large_chunks_and_degenerate():
    xy = np.array([[[0, 0], [300, 0], [0, 300]], [[5, 5], [5, 5], [6, 6]]], dtype=float)
    face, _ = rasterise(xy, 300, 300)
    assert (face == 1).sum() == 0
    assert abs((face == 0).sum() - 300 * 300 / 2) < 301
    with pytest.raises(ValueError):
        rasterise(np.full((1, 3, 2), np.nan), 4, 4)


# ----------------------------------------------------------------------------------------- atlas
def _uv_overlap_free(corner_uv, size=256):
    """Sum of UV triangle areas equals the area covered (no two charts share texels)."""
    px = uv_to_pixel(corner_uv, size, size)
    e1, e2 = px[:, 1] - px[:, 0], px[:, 2] - px[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
    count = 0
    for f in range(len(px)):
        face, _ = rasterise(px[f : f + 1], size, size)
        count += (face >= 0).sum()
    union, _ = rasterise(px, size, size)
    return area, count, (union >= 0).sum()


def test_unwrap_cylinder_charts_in_unit_square_without_overlap():
    part = cylinder(0.5, 2.0, segments=24)
    atlas = unwrap(part.vertices, part.faces, resolution=256, padding=2)
    assert atlas.method == "xatlas" and atlas.charts >= 1
    uv = atlas.corner_uv
    assert uv.shape == (len(part.faces), 3, 2) and np.isfinite(uv).all()
    assert uv.min() >= 0 and uv.max() <= 1
    area, count, union = _uv_overlap_free(uv)
    assert count == union  # every texel centre lies in at most one triangle
    assert abs(count - area) < 0.1 * area


def test_unwrap_degenerate_tiny_and_point_parts_have_finite_uvs():
    # All triangles zero-area (collinear), the sofa's degenerate parts' situation.
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], float)
    f = np.array([[0, 1, 2], [1, 2, 3]])
    a = unwrap(v, f)
    assert a.method == "planar" and np.isfinite(a.corner_uv).all()
    # A single point.
    a = unwrap(np.zeros((3, 3)), np.array([[0, 1, 2]]))
    assert np.isfinite(a.corner_uv).all() and np.allclose(a.corner_uv, 0.5)
    # A normal part with some zero-area faces mixed in.
    cv, cf = cube()
    v = np.vstack([cv, [[5, 5, 5]]])
    f = np.vstack([cf, [[0, 0, 1], [8, 8, 8]]])
    a = unwrap(v, f)
    assert a.method == "xatlas" and np.isfinite(a.corner_uv).all()
    assert any("zero-area" in n for n in a.notes)
    # A tiny part (1e-6 units) unwraps like a big one.
    a = unwrap(cv * 1e-6, cf)
    assert a.method == "xatlas" and np.isfinite(a.corner_uv).all()
    assert planar_uv(cv, cf).shape == (12, 3, 2)


def test_unwrap_validates():
    with pytest.raises(ValueError):
        unwrap(np.zeros((3, 3)), np.zeros((0, 3), int))
    with pytest.raises(ValueError):
        unwrap(np.full((3, 3), np.nan), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError):
        unwrap(np.zeros((3, 3)), np.array([[0, 1, 5]]))


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="threads are counted in /proc (Linux)")
def test_xatlas_is_built_without_threads():
    """The xatlas make setup installs starts no thread: its threaded scheduler's destructor can miss a
    worker's wake-up and hang for ever (proctex/texture/uv.py). A wheel from PyPI starts one or more."""
    from proctex.texture.uv import xatlas_threads

    assert xatlas_threads() == 0, "xatlas starts threads: `make xatlas-single-threaded` builds it without (needs g++ and cmake)"


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="thread states are read in /proc (Linux)")
def test_a_threaded_xatlas_is_destroyed_only_once_its_workers_sleep(monkeypatch):
    """_release destroys the Atlas once every worker was seen asleep twice in a row, and keeps it when
    they never settle: with real threads blocked on an event (asleep), and with states given in turn."""
    import threading
    import weakref

    from proctex.texture import uv as U

    class Thing:
        pass

    go, ids, threads, started = threading.Event(), [], [], threading.Semaphore(0)
    for _ in range(2):
        t = threading.Thread(target=lambda: (ids.append(str(threading.get_native_id())), started.release(), go.wait()), daemon=True)
        t.start()
        threads.append(t)
    assert started.acquire(timeout=30) and started.acquire(timeout=30)  # both threads run (then sleep on the event)
    holder = [Thing()]
    ref = weakref.ref(holder[0])
    assert U._release(holder, set(ids), settle_s=5.0) and ref() is None and holder == []
    go.set()
    for t in threads:
        t.join()
    # A worker awake, then asleep twice: destroyed after the second sleeping look, not before.
    looks = iter([False, True, False, True, True])
    monkeypatch.setattr(U, "_sleeping", lambda tid: next(looks))
    holder = [Thing()]
    ref = weakref.ref(holder[0])
    assert U._release(holder, {"1"}, settle_s=5.0) and ref() is None
    assert next(looks, "spent") == "spent"
    # Never asleep: kept, not destroyed.
    monkeypatch.setattr(U, "_sleeping", lambda tid: False)
    monkeypatch.setattr(U, "_KEPT", [])
    holder = [Thing()]
    ref = weakref.ref(holder[0])
    assert not U._release(holder, {"1"}, settle_s=0.05) and ref() is not None and U._KEPT == [ref()]
    # No workers (the single-threaded build): destroyed at once.
    holder = [Thing()]
    ref = weakref.ref(holder[0])
    assert U._release(holder, set()) and ref() is None


# ------------------------------------------------------------------------------------ texel maps
def test_texel_map_matches_reference_and_lies_on_surface():
    part = cylinder(0.4, 1.0, segments=10)
    atlas = unwrap(part.vertices, part.faces, resolution=32, padding=1)
    tm = texel_map(part.vertices, part.faces, atlas.corner_uv, 32)
    ref = texel_map_reference(part.vertices, part.faces, atlas.corner_uv, 32)
    got = {(int(i), int(j)): k for k, (i, j) in enumerate(tm.ij)}
    assert set(ref) <= set(got)
    for key, (face, lam) in ref.items():
        k = got[key]
        assert tm.face[k] == face
        assert np.allclose(tm.bary[k], np.clip(lam, 0, None) / np.clip(lam, 0, None).sum(), atol=1e-9)
    # Every face owns at least one texel; the extra (lonely-face) texels are exactly the difference.
    assert set(np.unique(tm.face)) == set(range(len(part.faces)))
    # Points are on the surface, and the texel's UV re-interpolated from its barycentrics is the centre.
    d = SurfaceIndex(part.vertices, part.faces).query(tm.points).distance
    assert d.max() < 1e-9
    uv = np.einsum("ij,ijk->ik", tm.bary, atlas.corner_uv[tm.face])
    inside = np.array([tuple(x) in ref for x in tm.ij])
    centre = np.stack([(tm.ij[:, 1] + 0.5) / 32, 1 - (tm.ij[:, 0] + 0.5) / 32], axis=1)
    assert np.allclose(uv[inside], centre[inside], atol=1e-9)
    assert np.allclose(np.linalg.norm(tm.normals, axis=1), 1)


def test_texel_map_gives_tiny_faces_a_texel():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, 0], [0.3001, 0.3, 0], [0.3, 0.3001, 0]], float)
    f = np.array([[0, 1, 2], [3, 4, 5]])
    uv = np.array([[[0.1, 0.1], [0.5, 0.1], [0.1, 0.5]], [[0.8, 0.8], [0.8001, 0.8], [0.8, 0.8001]]])
    tm = texel_map(v, f, uv, 16)
    assert (tm.face == 1).sum() == 1
    assert len(tm.face) == len(np.unique(tm.flat))


def test_pad_seams_fills_gutter_from_nearest_covered_texel():
    img = np.zeros((20, 20, 3), np.float32)
    mask = np.zeros((20, 20), bool)
    mask[5:8, 5:8] = True
    img[5:8, 5:8] = [1, 0, 0]
    img[5:8, 7] = [0, 1, 0]
    out, filled = pad_seams(img, mask, gutter=3)
    assert filled[6, 2:11].all() and filled[2:11, 6].all() and filled[4, 4] and filled[8, 9]
    assert not filled[1, 6] and not filled[6, 11] and not filled[2, 2]  # beyond 3 texels (Euclidean)
    assert np.allclose(out[6, 10], [0, 1, 0])  # right of the green column
    assert np.allclose(out[6, 2], [1, 0, 0])
    assert np.array_equal(out[mask], img[mask])
    full, everywhere = pad_seams(img, mask, gutter=-1)
    assert everywhere.all()


def test_sample_texture_bilinear_and_nearest():
    tex = np.arange(4 * 4 * 3, dtype=np.float64).reshape(4, 4, 3)
    centres = np.array([[(j + 0.5) / 4, 1 - (i + 0.5) / 4] for i in range(4) for j in range(4)])
    assert np.allclose(sample_texture(tex, centres), tex.reshape(-1, 3))
    mid = np.array([[0.25, 1 - 0.125]])  # between texels (0, 0) and (0, 1)
    assert np.allclose(sample_texture(tex, mid), (tex[0, 0] + tex[0, 1]) / 2)
    assert np.allclose(sample_texture(tex.astype(np.uint8), centres, bilinear=False) * 255, tex.reshape(-1, 3))


def _sample_reference(tex, uv):
    """Bilinear lookup texel by texel (edge-clamped), the slow way."""
    H, W = tex.shape[:2]
    out = []
    for u, v in uv:
        r = min(max((1 - v) * H - 0.5, 0), H - 1)
        c = min(max(u * W - 0.5, 0), W - 1)
        i0, j0 = min(int(np.floor(r)), max(H - 2, 0)), min(int(np.floor(c)), max(W - 2, 0))
        i1, j1 = min(i0 + 1, H - 1), min(j0 + 1, W - 1)
        fr, fc = r - i0, c - j0
        t = tex.astype(np.float64) / (255.0 if tex.dtype == np.uint8 else 1.0)
        out.append((t[i0, j0] * (1 - fc) + t[i0, j1] * fc) * (1 - fr) + (t[i1, j0] * (1 - fc) + t[i1, j1] * fc) * fr)
    return np.array(out)


@pytest.mark.parametrize("size", [(1, 1), (1, 6), (5, 1), (7, 9), (16, 16)])
def test_sample_texture_matches_a_texel_by_texel_reference(size):
    rng = np.random.default_rng(sum(size))
    uv = rng.uniform(-0.2, 1.2, (300, 2))  # outside the unit square too: clamped to the edge
    for tex in (rng.integers(0, 256, (*size, 3)).astype(np.uint8), rng.random((*size, 4))):
        assert np.allclose(sample_texture(tex, uv), _sample_reference(tex, uv), atol=1e-12)


def test_shape_uv_members_read_their_representatives_texture():
    shape = get_model("table").generate()
    grouping = analyse(shape)
    uv = shape_uv(shape, grouping, resolution=256)
    assert np.isfinite(uv.corner_uv).all() and (uv.face_group >= 0).all()
    # A texture that encodes position on the representative: members sample the same colour at
    # corresponding points (x_rep = R x + t).
    for g in grouping.groups:
        rep = grouping.parts[g.representative]
        tm = texel_map(shape.vertices, shape.faces[rep.faces], uv.corner_uv[rep.faces], 256)
        lo, hi = tm.points.min(0), tm.points.max(0)
        img = np.zeros((256, 256, 3))
        img[tm.ij[:, 0], tm.ij[:, 1]] = (tm.points - lo) / np.maximum(hi - lo, 1e-9)
        img, _ = pad_seams(img, tm.mask, 4)
        for member, mmap in zip(g.members[1:], g.maps[1:]):
            part = grouping.parts[member]
            f = part.faces
            centroid_uv = uv.corner_uv[f].mean(axis=1)
            x = shape.vertices[shape.faces[f]].mean(axis=1) @ mmap.R.T + mmap.t
            expected = (x - lo) / np.maximum(hi - lo, 1e-9)
            got = sample_texture(img, centroid_uv)
            assert np.median(np.abs(got - expected)) < 0.02, (g.index, member, mmap.method)


def test_source_uv_keeps_a_given_layout_and_members_follow_their_representative():
    """A source's UVs (here the unwrap's own, as if a Blender graph had made them) are kept for each
    representative exactly; members get theirs as :func:`shape_uv` gives them; a layout outside
    [0, 1] is moved in (aspect kept); one with no extent is unwrapped instead, with a note."""
    shape = get_model("table").generate()
    grouping = analyse(shape)
    made = shape_uv(shape, grouping, resolution=128)
    kept = source_uv(shape, grouping, made.corner_uv, resolution=128)
    assert np.allclose(kept.corner_uv, made.corner_uv) and np.array_equal(kept.face_group, made.face_group)
    assert all(a.method == "source" and not a.notes for a in kept.atlases)
    moved = source_uv(shape, grouping, made.corner_uv * 3.0 - 1.0, resolution=128)
    for g in grouping.groups:
        f = grouping.parts[g.representative].faces
        a, b = moved.corner_uv[f].reshape(-1, 2), made.corner_uv[f].reshape(-1, 2)
        assert a.min() >= 0.0 and a.max() <= 1.0
        assert np.allclose(np.corrcoef(a[:, 0], b[:, 0])[0, 1], 1.0) and np.allclose(np.corrcoef(a[:, 1], b[:, 1])[0, 1], 1.0)
        ratio = np.ptp(a, axis=0) / np.maximum(np.ptp(b, axis=0), 1e-12)
        assert np.isclose(ratio[0], ratio[1], rtol=1e-6)  # one scale for u and v
        assert any("moved into [0, 1]" in n for n in moved.atlases[g.index].notes)
    flat = source_uv(shape, grouping, np.zeros_like(made.corner_uv), resolution=128)
    assert all(a.method in ("xatlas", "planar") and any("no extent" in n for n in a.notes) for a in flat.atlases)
    folded = made.corner_uv.copy()
    rep = grouping.parts[grouping.groups[0].representative].faces
    folded[rep] = folded[rep[0]]  # every face of the representative on one triangle: heavy overlap
    assert any("overlap" in n for n in source_uv(shape, grouping, folded, resolution=128).atlases[0].notes)
    with pytest.raises(ValueError, match="corner_uv"):
        source_uv(shape, grouping, made.corner_uv[:-1])
    with pytest.raises(ValueError, match="no extent"):
        fit_unit_square(np.ones((4, 3, 2)))


# ----------------------------------------------------------------------------------------- render
def test_camera_projects_its_own_rays_to_pixel_centres():
    cam = Camera((3.0, -2.0, 1.5), (0.1, 0.2, 0.0), (0, 0, 1), 45.0, 16, 12)
    origins, dirs = cam.rays()
    xy, z = cam.project(origins + 2.5 * dirs)
    jj, ii = np.meshgrid(np.arange(16) + 0.5, np.arange(12) + 0.5)
    assert np.allclose(xy[:, 0], jj.ravel()) and np.allclose(xy[:, 1], ii.ravel())
    assert (z > 0).all()
    with pytest.raises(ValueError):
        Camera((0, 0, 0), (0, 0, 0))


def test_render_plane_depth_normal_and_cosine():
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    cam = Camera((0, 0, 6.0), (0, 0, 0), (0, 1, 0), 30.0, 33, 33)
    for backend in ["raster"] + (["embree"] if embree_available() else []):
        b = render_buffers(Tracer(v, f, backend), cam)
        assert b.mask[16, 16] and np.isclose(b.depth[16, 16], 6.0)
        assert np.allclose(b.normal[b.mask], [0, 0, 1]) and np.isclose(b.cos[16, 16], 1.0)
        assert np.allclose(np.abs(b.points[b.mask][:, 2]), 0)
        recon = np.einsum("ij,ijk->ik", b.bary[b.mask], v[f[b.face[b.mask]]])
        assert np.allclose(recon, b.points[b.mask])
        assert not b.mask[0, 0] and np.isinf(b.depth[0, 0])


@pytest.mark.skipif(not embree_available(), reason="embreex not installed")
def test_embree_and_raster_backends_agree():
    shape = get_model("chair").generate()
    grouping = analyse(shape)
    c, r = bounding_sphere(shape.vertices)
    te, tr = Tracer(shape.vertices, shape.faces, "embree"), Tracer(shape.vertices, shape.faces, "raster")
    for cam in canonical_cameras(c, r, "z", 96) + orbit_path(c, r, "z", 11, 96)[:3]:
        be = render_buffers(te, cam, grouping.segmentation.face_part)
        br = render_buffers(tr, cam, grouping.segmentation.face_part)
        assert (be.mask == br.mask).mean() > 0.995
        both = be.mask & br.mask & (be.face == br.face)
        assert both.sum() > 0.99 * be.mask.sum()
        assert np.allclose(be.depth[both], br.depth[both])
        assert (be.part[both] == br.part[both]).all()


def test_camera_sets():
    c, r = np.zeros(3), 1.0
    six = canonical_cameras(c, r, "z", 32)
    assert [cam.name for cam in six] == ["front", "back", "left", "right", "top", "bottom"]
    fwd = np.array([cam.basis()[2] for cam in six])
    assert np.allclose(fwd[4], [0, 0, -1]) and np.allclose(fwd[5], [0, 0, 1])
    assert np.allclose(fwd[0], [0, 1, 0])  # z-up front view looks along +y (from -y)
    assert np.allclose(canonical_cameras(c, r, "y", 32)[0].basis()[2], [0, 0, -1])
    assert len(orbit_path(c, r, "z", 11)) == 11 and len({cam.eye for cam in orbit_path(c, r, "z", 11)}) == 11
    assert len(turntable(c, r, "z", 7)) == 7
    assert default_up("sofa.obj") == "y" and default_up("chair") == "z"
    with pytest.raises(ValueError):
        orbit_path(c, r, "q", 11)


def test_whole_shape_visible_in_every_canonical_view(tmp_path):
    shape = get_model("mug").generate()
    c, r = bounding_sphere(shape.vertices)
    tracer = Tracer(shape.vertices, shape.faces)
    for cam in canonical_cameras(c, r, "z", 64):
        b = render_buffers(tracer, cam)
        assert b.mask.any()
        # Nothing touches the border: the shape fits in view.
        assert not (b.mask[0].any() or b.mask[-1].any() or b.mask[:, 0].any() or b.mask[:, -1].any())
    save_png(tmp_path / "x.png", np.zeros((4, 4, 3)))
    assert (tmp_path / "x.png").stat().st_size > 0
    with pytest.raises(ValueError):
        save_png(tmp_path / "y.png", np.zeros((4, 4)))
    assert not list(tmp_path.glob("*.tmp*"))


def test_shape_without_faces_is_rejected():
    with pytest.raises(ValueError):
        Tracer(np.zeros((3, 3)), np.zeros((0, 3), int))
    shape = Shape(np.zeros((3, 3)), np.array([[0, 1, 2]]))
    assert triangle_areas(shape.vertices, shape.faces)[0] == 0


def test_views_traced_once_serve_every_uv_layout():
    """One tracing of a mesh's six views gives the coverage and the renders of any UV layout exactly
    as tracing again; views of another size or mesh are refused."""
    from proctex.texture.metrics import coverage

    shape = get_model("mug").generate()
    uv = shape_uv(shape, analyse(shape), resolution=64)
    rng = np.random.default_rng(0)
    textures = [rng.integers(0, 256, (64, 64, 3)).astype(np.uint8) for _ in range(int(uv.face_group.max()) + 1)]
    painted = [rng.random((64, 64)) > 0.3 for _ in textures]
    views = canonical_buffers(shape.vertices, shape.faces, "z", 48)
    for face_group in (uv.face_group, np.where(uv.face_group == 0, -1, uv.face_group)):  # and a layout with a group left bare
        a = coverage(shape.vertices, shape.faces, uv.corner_uv, face_group, painted, size=48)
        b = coverage(shape.vertices, shape.faces, uv.corner_uv, face_group, painted, size=48, views=views)
        assert a == b and 0 < a.share < 1
        imgs, _ = render_six_views(shape.vertices, shape.faces, uv.corner_uv, face_group, textures, "z", 48)
        again, _ = render_six_views(shape.vertices, shape.faces, uv.corner_uv, face_group, textures, "z", 48, views=views)
        assert all(np.array_equal(x, y) for x, y in zip(imgs, again))
    labelled = with_labels(views[0], face_group=uv.face_group)
    assert np.array_equal(labelled.group, render_buffers(Tracer(shape.vertices, shape.faces), views[0].camera, face_group=uv.face_group).group)
    assert (views[0].group == -1).all()  # the traced views keep no labels
    with pytest.raises(ValueError, match="six canonical"):
        coverage(shape.vertices, shape.faces, uv.corner_uv, uv.face_group, painted, size=64, views=views)
    with pytest.raises(ValueError, match="six canonical"):
        coverage(shape.vertices, shape.faces[:10], uv.corner_uv[:10], uv.face_group[:10], painted, size=48, views=views)
    with pytest.raises(ValueError, match="face_group"):
        coverage(shape.vertices, shape.faces, uv.corner_uv, uv.face_group[:-1], painted, size=48, views=views)
    with pytest.raises(ValueError, match="face_group"):
        render_six_views(shape.vertices, shape.faces, uv.corner_uv, uv.face_group[:-1], textures, "z", 48, views=views)
