import json

import numpy as np
import pytest

from proctex.geometry import primitives as P
from proctex.geometry.matching import match_groups
from proctex.geometry.meshio import load_mesh
from proctex.geometry.parts import analyse, connected_parts, segment, symmetry_planes
from proctex.geometry.shape import Shape, ShapeBuilder


def chiral_block():
    """A box with one corner pulled in: no mirror symmetry of its own."""

    def warp(local, canon):
        local[:, 0] -= 0.3 * canon[:, 2] * canon[:, 1]  # shear x by height and depth
        local[:, 2] -= 0.2 * canon[:, 0] * (1 - canon[:, 1])
        return local

    return P.box((1.0, 0.6, 0.8), divisions=(2, 2, 2), warp=warp)


def table_like(n_legs=4, mirrored=True, jitter=0.0):
    """Top + n identical legs + (optionally) a chiral block and its mirror image + a degenerate part."""
    b = ShapeBuilder()
    b.add(P.box((2.0, 1.0, 0.1), center=(0, 0, 1.0), divisions=(4, 2, 1)), "top")
    leg = P.box((0.1, 0.1, 0.9), divisions=(1, 1, 3))
    for k in range(n_legs):
        a = 2 * np.pi * k / n_legs
        b.add(P.transform(leg, R=P.rotation("z", a), t=(0.7 * np.cos(a), 0.35 * np.sin(a), 0.45)), "leg")
    if mirrored:
        blk = P.transform(chiral_block(), t=(1.5, 0, 0.5))
        b.add(blk, "block")
        b.add(P.mirror(blk, axis=0, plane=0.0), "block")
    flat = P.box((0.3, 0.3, 0.3), center=(0, 0, 2))
    flat.vertices[:] = flat.vertices[0]  # collapsed: every triangle has zero area
    b.add(flat, "degenerate")
    shape = b.build()
    if jitter:
        solid = shape.vertex_label_names() != "degenerate"
        shape.vertices[solid] += np.random.default_rng(0).normal(0, jitter, (solid.sum(), 3))
    return shape


def test_connected_parts_by_index_not_position():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0], [1, 0, 0], [0, -1, 0], [5, 5, 5]], float)
    f = np.array([[0, 1, 2], [3, 5, 4]])  # coincident vertices, different indices
    face_part, vertex_part, n = connected_parts(f, len(v))
    assert n == 2
    np.testing.assert_array_equal(face_part, [0, 1])
    assert vertex_part[6] == -1


def test_exact_part_and_group_counts_on_hand_built_shape():
    shape = table_like(n_legs=4)
    g = analyse(shape)
    assert len(g.parts) == 1 + 4 + 2 + 1
    by_label = {}
    for p in g.parts:
        by_label.setdefault(p.label, set()).add(int(g.part_group[p.index]))
    assert all(len(groups) == 1 for groups in by_label.values())  # each label is one group
    assert len(g.groups) == 4
    deg = [p for p in g.parts if p.degenerate]
    assert len(deg) == 1 and deg[0].label == "degenerate" and deg[0].area == 0
    legs = g.groups[g.part_group[1]]
    assert legs.members == [1, 2, 3, 4]
    # Every member map really carries the member onto the representative.
    for mm in legs.maps:
        member = shape.vertices[g.parts[mm.part].vertices]
        rep = shape.vertices[g.parts[legs.representative].vertices]
        moved = member @ mm.R.T + mm.t
        d = np.linalg.norm(moved[:, None] - rep[None], axis=2).min(1)
        assert d.max() < 1e-9
    blocks = g.groups[g.part_group[5]]
    assert blocks.members == [5, 6]
    assert blocks.maps[1].mirrored and not blocks.maps[0].mirrored


def test_mirrored_part_needs_a_reflection():
    blk = chiral_block()
    mir = P.mirror(blk, axis=0)
    from proctex.geometry.align import umeyama, apply

    R, t, _ = umeyama(mir.vertices, blk.vertices, reflection=False)
    assert np.abs(apply(mir.vertices, R, t) - blk.vertices).max() > 0.05  # no rotation does it


def test_grouping_by_icp_when_topology_differs():
    """Same leg geometry, different triangulation: the ICP path must group them."""
    b = ShapeBuilder()
    b.add(P.box((0.1, 0.1, 0.9), center=(0, 0, 0), divisions=(1, 1, 3)), "leg")
    b.add(P.box((0.1, 0.1, 0.9), center=(1, 0, 0), divisions=(2, 2, 5)), "leg")
    b.add(P.box((0.1, 0.1, 1.2), center=(2, 0, 0), divisions=(1, 1, 3)), "longer")
    g = analyse(b.build())
    assert g.part_group.tolist() == [0, 0, 1]
    assert g.groups[0].maps[1].method == "icp"


def test_tolerance_is_relative_to_size():
    # Scaling the whole shape by 1000 or 0.001 must not change the grouping.
    base = table_like()
    ref = analyse(base).part_group
    for s in (1e-3, 1e3):
        scaled = Shape(base.vertices * s, base.faces, labels=base.labels, label_names=base.label_names)
        np.testing.assert_array_equal(analyse(scaled).part_group, ref)


def test_symmetry_plane_detected():
    planes = symmetry_planes(table_like(n_legs=4))
    normals = np.array([p.normal for p in planes])
    assert np.any(np.abs(normals @ [1, 0, 0]) > 0.999)


def test_match_groups_reports_added_and_missing():
    template = table_like(n_legs=4, mirrored=True)
    shape = table_like(n_legs=4, mirrored=False)
    tg, sg = analyse(template), analyse(shape)
    m = match_groups(shape, sg, template, tg)
    label = lambda g, i: g.groups[i].label  # noqa: E731
    assert all(label(sg, a) == label(tg, b) for a, b in m.pairs)
    assert [label(tg, j) for j in m.missing] == ["block"]
    assert m.added == []
    m2 = match_groups(template, tg, shape, sg)
    assert [label(tg, i) for i in m2.added] == ["block"] and m2.missing == []


def test_match_groups_survives_part_count_change_and_noise():
    template = analyse(table_like(n_legs=4))
    shape_shape = table_like(n_legs=6, jitter=1e-4)
    sg = analyse(shape_shape)
    m = match_groups(shape_shape, sg, table_like(n_legs=4), template)
    assert len(m.pairs) == 4 and not m.added and not m.missing
    assert all(sg.groups[a].label == template.groups[b].label for a, b in m.pairs)


def test_segment_rejects_empty():
    with pytest.raises(ValueError):
        segment(Shape(np.zeros((3, 3)), np.zeros((0, 3), int)))


# ------------------------------------------------------------------------------------------- sofa
SOFA_GROUPS = [[0, 1], [2], [3], [4], [5], [6], [7], [8]]


def test_sofa_segmentation(sofa_dir):
    shape, _ = load_mesh(sofa_dir / "train" / "0.obj")
    g = analyse(shape)
    d = g.to_dict()
    assert len(d["parts"]) == 9
    assert [p["degenerate"] for p in d["parts"]] == [False, False, False, True, True, False, False, True, True]
    # Armrests (0, 1) are one group, mirrored across x = 0; the rest are singletons.
    assert [grp["parts"] for grp in d["groups"]] == SOFA_GROUPS
    # The armrests are each symmetric, so the right one is a translated copy of the left.
    mm = g.groups[0].maps[1]
    np.testing.assert_allclose(mm.R, np.eye(3), atol=1e-3)
    assert abs(mm.t[0] - 2 * g.parts[0].center[0]) < 1e-3 and mm.error < 1e-3
    assert [p["faces"] for p in d["parts"]] == [432, 432, 432, 576, 576, 1728, 1728, 576, 576]
    # What the parts are (inspected in the data: y up, x across, the back towards -z):
    c = np.array([p.center for p in g.parts])
    lo = np.array([shape.vertices[p.vertices].min(0) for p in g.parts])
    hi = np.array([shape.vertices[p.vertices].max(0) for p in g.parts])
    assert hi[0, 0] == pytest.approx(shape.vertices[:, 0].max()) and lo[1, 0] == pytest.approx(shape.vertices[:, 0].min())  # armrests
    assert np.argmin(c[:, 1]) == 2  # the base is the lowest part
    assert c[5, 2] < -0.2 < c[6, 2] and hi[5, 1] == pytest.approx(shape.vertices[:, 1].max())  # back cushion, seat cushion
    json.dumps(d)


def test_sofa_group_matching_sample(sofa_dir):
    template, _ = load_mesh(sofa_dir / "train" / "0.obj")
    tg = analyse(template)
    for name in ("inference/7.obj", "train/13.obj"):
        shape, _ = load_mesh(sofa_dir / name)
        sg = analyse(shape)
        m = match_groups(shape, sg, template, tg)
        assert m.pairs == [(i, i) for i in range(8)] and not m.added and not m.missing


def test_a_uniformly_scaled_copy_joins_its_group_and_its_scale_is_recovered():
    """A chiral block, a copy scaled by 0.5, turned and moved, and a copy stretched along one axis
    only: the scaled copy shares the block's group (a "similar" member whose map carries it back
    exactly, scale 2), the stretched one does not; ``similar=False`` keeps the old rigid grouping."""
    blk = chiral_block()
    b = ShapeBuilder()
    b.add(blk, "block")
    b.add(P.transform(P.transform(blk, R=P.rotation("z", 0.7)), t=(3.0, 1.0, 0.0)), "block")
    small = chiral_block()
    small.vertices[:] = small.vertices * 0.5 @ P.rotation("z", 0.7).T + np.array([3.0, 1.0, 0.0])
    b.add(small, "small")
    long = chiral_block()
    long.vertices[:, 2] *= 1.5
    long.vertices[:] += np.array([-3.0, 0.0, 0.0])
    b.add(long, "long")
    shape = b.build()
    g = analyse(shape)
    assert g.part_group.tolist() == [0, 0, 0, 1]
    methods = [m.method for m in g.groups[0].maps]
    assert methods == ["self", "topology", "similar"], methods
    mm = g.groups[0].maps[2]
    assert abs(mm.scale - 2.0) < 1e-9 and not mm.mirrored  # exact copies: off by 8.9e-16 (rounding): x1e6 below the bound
    member = shape.vertices[g.parts[2].vertices]
    rep = shape.vertices[g.parts[0].vertices]
    np.testing.assert_allclose(member @ mm.R.T + mm.t, rep, atol=1e-9)  # vertex i onto vertex i
    np.testing.assert_allclose(mm.inverse(rep), member, atol=1e-9)
    np.testing.assert_allclose(mm.rotation @ mm.rotation.T, np.eye(3), atol=1e-9)  # the map between normalised frames
    assert analyse(shape, similar=False).part_group.tolist() == [0, 0, 1, 2]


def bent_grid(n=5, seed=0, flip=()):
    """An n x n vertex grid sheet, each vertex moved its own way (seeded), its quads split along
    one diagonal except those in ``flip`` (split along the other, as an exporter splitting each
    moved quad along its shorter diagonal does)."""
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    verts = np.stack([u.ravel(), v.ravel(), 0.3 * np.sin(3 * u.ravel()) * (1 + seed)], axis=1) + rng.normal(0, 0.03, (n * n, 3))
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            faces += [[a, b, d], [b, c, d]] if (i, j) in flip else [[a, b, c], [a, c, d]]
    return P.Part(verts, np.array(faces, dtype=np.int64), np.zeros_like(verts))


def test_in_a_scene_of_many_parts_copies_moved_vertex_by_vertex_share_a_group(monkeypatch):
    """Above ICP_PARTS parts (lowered here to 2), sheets with the same vertices moved each its own way
    and two quads split the other way join one group ("deformed": vertex i is the representative's
    vertex i); a sheet of another vertex count, and one with most faces on other vertices, do not.
    A deformed member's UVs are the representative's on every face they share; its texels lie at the
    same barycentrics on its own vertices."""
    import proctex.geometry.parts as parts_mod
    from proctex.texture.paint_loop import _member
    from proctex.texture.uv import member_corner_uv, texel_map

    monkeypatch.setattr(parts_mod, "ICP_PARTS", 2)
    b = ShapeBuilder()
    b.add(bent_grid(seed=0), "sheet")
    b.add(P.transform(bent_grid(seed=1, flip={(0, 0), (2, 3)}), t=(2.0, 0, 0)), "sheet")
    b.add(P.transform(bent_grid(n=6, seed=2), t=(4.0, 0, 0)), "sheet")
    other = bent_grid(seed=3)
    other.faces[:] = np.random.default_rng(1).permutation(len(other.vertices))[other.faces]  # the same grid, its vertices renumbered
    b.add(P.transform(other, t=(6.0, 0, 0)), "sheet")
    shape = b.build()
    g = analyse(shape)
    assert g.part_group.tolist() == [0, 0, 1, 2]
    mm = g.groups[0].maps[1]
    assert mm.method == "deformed" and mm.error > 0.01  # no rigid or similar copy (0.099 on both kernel sets: x10)
    np.testing.assert_allclose(mm.rotation @ mm.rotation.T, np.eye(3), atol=1e-9)
    with monkeypatch.context() as m:
        m.setattr(parts_mod, "ICP_PARTS", 300)
        assert analyse(shape).part_group.tolist() == [0, 1, 2, 3]  # few parts: rigid copies only
    rep, mem = g.parts[0], g.parts[1]
    xy = shape.vertices[shape.faces[rep.faces]][..., :2]
    rep_uv = 0.05 + 0.9 * (xy - xy.min((0, 1))) / np.ptp(xy, axis=(0, 1))  # (k, 3, 2) inside [0, 1]
    uv = member_corner_uv(shape, rep, rep_uv, mem, mm)
    local_rep = np.sort(np.searchsorted(rep.vertices, shape.faces[rep.faces]), axis=1)
    local_mem = np.searchsorted(mem.vertices, shape.faces[mem.faces])
    same = [k for k in range(mem.n_faces) if any((np.sort(local_mem[k]) == local_rep).all(1))]
    assert len(same) == mem.n_faces - 4
    for k in same:  # the UV of each corner is the UV the representative gives that vertex
        r = int(np.flatnonzero((np.sort(local_mem[k]) == local_rep).all(1))[0])
        for c in range(3):
            at = int(np.flatnonzero(np.searchsorted(rep.vertices, shape.faces[rep.faces][r]) == local_mem[k, c])[0])
            np.testing.assert_allclose(uv[k, c], rep_uv[r, at], atol=1e-9)
    texels = texel_map(shape.vertices, shape.faces[rep.faces], rep_uv, 32)
    pts = _member(shape, g, g.groups[0], mm, texels).texel_points(texels)
    local = np.searchsorted(rep.vertices, shape.faces[rep.faces])[texels.face]  # the representative's corners, member's vertices
    np.testing.assert_allclose(pts, np.einsum("tk,tkd->td", texels.bary, shape.vertices[mem.vertices][local]), atol=1e-12)
    assert np.abs(pts - texels.points).max() > 1.0  # not the representative's own points


def test_shared_faces_counts_faces_on_the_same_vertices_in_any_corner_order():
    from proctex.geometry.parts import shared_faces

    fa = np.array([[0, 1, 2], [1, 2, 3], [2, 3, 4], [3, 4, 5]])
    fb = np.array([[2, 1, 0], [3, 2, 4], [0, 3, 5]])  # the first two turned, one other
    assert shared_faces(fa, fb) == 0.5 and shared_faces(fb, fa) == 2 / 3 and shared_faces(fa[:0], fb) == 0.0
    big = 3_000_000  # indices whose cube overflows int64: the same count another way
    assert shared_faces(fa + big, fb + big) == 0.5


def test_a_shapes_segmentation_is_a_declared_field_a_new_shape_starts_without():
    """What is computed once per shape lives in its declared ``derived`` field (issue 55: the
    segmentation hid in an undeclared attribute): parts_of fills it once, a replaced array is seen, a
    copy made by ``dataclasses.replace`` starts empty, and it is in no comparison or repr."""
    from dataclasses import fields, replace

    from proctex.geometry.parts import parts_of
    from proctex.models import get_model

    shape = get_model("mug").generate({})
    assert "derived" in {f.name for f in fields(Shape)} and shape.derived == {}
    seg = parts_of(shape)
    assert parts_of(shape) is seg and shape.derived["parts"][2] is seg
    moved = replace(shape, vertices=shape.vertices + 1.0)
    assert moved.derived == {} and parts_of(moved) is not seg and len(parts_of(moved).parts) == len(seg.parts)
    shape.faces = shape.faces.copy()  # an array replaced: computed again
    assert parts_of(shape) is not seg
    (field,) = [f for f in fields(Shape) if f.name == "derived"]
    assert (field.init, field.compare, field.repr) == (False, False, False) and "derived=" not in repr(shape)


def test_a_parts_local_faces_are_the_searched_ones_and_read_only():
    """``segment`` gives each part its faces in local vertex indices (``PartInfo.local``, what
    ``part_mesh`` returns): on a shape whose vertices are shuffled, with unreferenced vertices and
    a part of one triangle, they equal the faces found by search in the part's sorted vertices, and
    they are read-only (a caller writing into them would change every later transfer's part)."""
    from proctex.geometry.parts import part_mesh

    rng = np.random.default_rng(0)
    a, b = P.box((1.0, 0.6, 0.8), divisions=(2, 2, 2)), P.box((0.2, 0.2, 1.0), center=(3.0, 0, 0), divisions=(1, 1, 3))
    v = np.concatenate([a.vertices, b.vertices, [[9.0, 9, 9], [9, 10, 9], [10, 9, 9]], rng.normal(size=(4, 3))])
    f = np.concatenate([a.faces, b.faces + len(a.vertices), [len(a.vertices) + len(b.vertices) + np.arange(3)]])
    perm = rng.permutation(len(v))  # vertices shuffled: parts' vertices interleave in index order
    inv = np.argsort(perm)
    shape = Shape(v[perm], inv[f])
    seg = segment(shape)
    assert len(seg.parts) == 3
    for part in seg.parts:
        verts, local = part_mesh(shape, part)
        assert np.array_equal(local, np.searchsorted(part.vertices, shape.faces[part.faces]))
        assert np.array_equal(verts[local], shape.vertices[shape.faces[part.faces]])
        with pytest.raises(ValueError, match="read-only"):
            local[0, 0] = 0


def _component_soup(seed: int):
    """Faces over shuffled vertices: parts touching at a shared vertex (one part), a chain whose
    faces come in no particular order, degenerate faces ([v, v, v], [v, v, w]), faces used twice,
    vertices no face uses, and a random soup of 300 faces over 400 vertices."""
    rng = np.random.default_rng(seed)
    chain = np.array([[0, 1, 2], [5, 6, 7], [2, 3, 4], [4, 5, 8], [9, 9, 9], [10, 10, 11], [12, 13, 14], [14, 15, 12], [12, 13, 14]])
    soup = rng.integers(20, 420, (300, 3))
    f = np.concatenate([chain, soup])[rng.permutation(len(chain) + 300)]
    perm = rng.permutation(430)
    return perm[f], 430


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compiled_components_and_areas_are_the_array_forms(seed, monkeypatch):
    """``connected_parts`` (union-find, compiled) against scipy's components: the same parts
    numbered the same way (by first face), the same vertex parts (-1 unreferenced) and count, on a
    soup with touching parts, degenerate and repeated faces and unused vertices; ``triangle_areas``
    bit for bit; and with numba hidden the array forms answer. A plausible wrong numbering (parts
    in order of their smallest vertex) differs on the soup."""
    import sys

    from proctex.geometry.parts import connected_parts, connected_parts_arrays
    from proctex.geometry.surface import triangle_areas, triangle_areas_arrays

    f, n = _component_soup(seed)
    got, want = connected_parts(f, n), connected_parts_arrays(f, n)
    assert got[2] == want[2] and np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
    assert got[0].dtype == np.int64 and got[1].dtype == np.int64 and (got[1] == -1).sum() > 0
    by_vertex = np.unique(np.array([f[got[0] == p].min() for p in range(got[2])]), return_inverse=True)[1]
    assert not np.array_equal(by_vertex[got[0]], got[0])  # the numbering the test would catch
    v = np.random.default_rng(seed).normal(size=(n, 3)) * 10.0 ** np.random.default_rng(seed).integers(-6, 6, (n, 1))
    # bit for bit, natively and with AVX-512 off (tests.portable): the same operations in the same order, no margin
    assert np.array_equal(triangle_areas(v, f).view(np.int64), triangle_areas_arrays(v, f).view(np.int64))
    monkeypatch.setitem(sys.modules, "proctex.geometry.mesh_kernels", None)  # its import raises ImportError
    hidden = connected_parts(f, n)
    assert hidden[2] == want[2] and np.array_equal(hidden[0], want[0]) and np.array_equal(triangle_areas(v, f), triangle_areas_arrays(v, f))


def test_compiled_components_refuse_bad_faces():
    from proctex.geometry.mesh_kernels import connected_parts, triangle_areas

    with pytest.raises(ValueError, match="index vertices"):
        connected_parts(np.array([[0, 1, 5]]), 5)
    with pytest.raises(ValueError, match=r"\(m, 3\)"):
        connected_parts(np.array([0, 1, 2]), 5)
    with pytest.raises(ValueError, match="index vertices"):
        triangle_areas(np.zeros((3, 3)), np.array([[0, 1, -1]]))
    assert connected_parts(np.zeros((0, 3), np.int64), 3)[2] == 0


def test_a_part_is_degenerate_exactly_when_its_largest_triangle_is_below_the_bound():
    """``segment``'s per-part largest triangle (one pass over the faces in part order) against a
    loop over the parts: degenerate parts and real ones, with
    the same flags, areas and part order (a point, a line and a triangle 1e-7 across are degenerate)."""
    from proctex.geometry.surface import triangle_areas_arrays

    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5], [6, 5, 5], [7, 5, 5], [9, 9, 9], [2, 2, 2], [3, 2, 2], [2, 3, 2 + 1e-9], [4, 4, 4], [4, 4, 4 + 1e-7], [4, 4 + 1e-7, 4]])
    f = np.array([[3, 4, 5], [0, 1, 2], [6, 6, 6], [7, 8, 9], [10, 11, 12], [4, 5, 3]])
    shape = Shape(v, f)
    seg = segment(shape)
    areas = triangle_areas_arrays(v, f)
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    for part in seg.parts:
        assert part.degenerate == bool(areas[part.faces].max() <= 1e-12 * diag**2)
        assert part.area == pytest.approx(areas[part.faces].sum())
    assert [p.degenerate for p in seg.parts] == [True, False, True, False, True]  # a line, a triangle, a point, a triangle, one 1e-7 across
