import numpy as np
import pytest

from proctex.geometry.meshio import clean_mesh, load_mesh, read_obj, save_mesh, triangulate
from proctex.geometry.parts import connected_parts, segment
from proctex.geometry.shape import Shape

from .meshes import cube, soup, two_cubes_touching


def n_parts(shape):
    return connected_parts(shape.faces, shape.n_vertices)[2]


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def obj_with_seams():
    """A cube whose OBJ uses vt/vn indices that differ per face corner (UV and normal seams)."""
    v, f = cube()
    lines = [f"v {x} {y} {z}" for x, y, z in v]
    lines += [f"vt {u} {w}" for u in (0, 1) for w in (0, 1)]
    lines += ["vn 1 0 0", "vn 0 1 0", "vn 0 0 1"]
    for i, (a, b, c) in enumerate(f + 1):
        t = i % 4 + 1
        lines.append(f"f {a}/{t}/{i % 3 + 1} {b}/{(t % 4) + 1}/{i % 3 + 1} {c}/{((t + 1) % 4) + 1}/{i % 3 + 1}")
    return "\n".join(lines) + "\n"


def test_obj_with_uv_normal_seams_keeps_parts_whole(tmp_path):
    p = write(tmp_path, "seams.obj", obj_with_seams())
    shape, report = load_mesh(p)
    assert shape.n_vertices == 8 and shape.n_faces == 12
    assert n_parts(shape) == 1


def test_trimesh_splits_seams_but_we_do_not(tmp_path):
    # The naive loader splits this OBJ along its seams; our loader must not depend on that.
    import trimesh

    p = write(tmp_path, "seams.obj", obj_with_seams())
    naive = trimesh.load(p, process=False)
    assert len(naive.vertices) > 8
    shape, _ = load_mesh(p)
    assert n_parts(shape) == 1


def test_touching_parts_stay_apart(tmp_path):
    v, f = two_cubes_touching()
    p = tmp_path / "touch.obj"
    save_mesh(Shape(v, f), p)
    for mode in ("auto", "index", "stitch"):
        shape, _ = load_mesh(p, connectivity=mode)
        assert n_parts(shape) == 2, mode
        assert shape.n_vertices == 16
    # A full positional weld merges them: that is why it is not the default.
    shape, _ = load_mesh(p, connectivity="weld")
    assert n_parts(shape) == 1


def test_soup_of_touching_cubes_comes_out_as_its_parts(tmp_path):
    v, f = two_cubes_touching()
    sv, sf = soup(v, f)
    p = tmp_path / "soup.obj"
    save_mesh(Shape(sv, sf), p)
    shape, report = load_mesh(p)
    assert n_parts(shape) == 2
    assert shape.n_vertices == 16 and shape.n_faces == 24
    assert report.stitched_edges == 36  # 18 undirected edges per cube


def test_stl_round_trip_recovers_parts(tmp_path):
    v, f = two_cubes_touching()
    p = tmp_path / "touch.stl"
    save_mesh(Shape(v, f), p)
    shape, _ = load_mesh(p)
    assert n_parts(shape) == 2 and shape.n_vertices == 16


@pytest.mark.parametrize("ext", ["obj", "ply", "glb", "stl"])
def test_round_trip_every_format(tmp_path, ext):
    from proctex.models import get_model

    shape = get_model("desk").generate({"drawers": 2})
    p = tmp_path / f"desk.{ext}"
    save_mesh(shape, p)
    back, _ = load_mesh(p)
    # The same bytes without a file (an upload, a store object): the same mesh.
    from proctex.geometry.meshio import load_mesh_bytes

    same, report = load_mesh_bytes(p.read_bytes(), f"upload.{ext}")
    np.testing.assert_array_equal(same.vertices, back.vertices)
    np.testing.assert_array_equal(same.faces, back.faces)
    assert same.source == f"upload.{ext}" and report.path == f"upload.{ext}"
    assert n_parts(back) == n_parts(shape)
    assert back.n_faces == shape.n_faces
    seg_a, seg_b = segment(shape), segment(back)
    assert sorted(p.n_faces for p in seg_a.parts) == sorted(p.n_faces for p in seg_b.parts)
    if ext in ("obj", "ply", "glb"):
        np.testing.assert_allclose(back.vertices, shape.vertices, atol=1e-6)


def test_gltf_split_vertices_are_stitched(tmp_path):
    # A glTF primitive with per-face vertices (as exporters do along UV seams) next to a touching cube.
    import trimesh

    v, f = two_cubes_touching()
    sv, sf = soup(v[:8], f[:12])
    verts = np.concatenate([sv, v[8:]])
    faces = np.concatenate([sf, f[12:] - 8 + len(sv)])
    p = tmp_path / "split.glb"
    trimesh.Trimesh(verts, faces, process=False).export(p)
    shape, report = load_mesh(p)
    assert report.format == "glb"
    assert n_parts(shape) == 2


def test_polygons_are_triangulated(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0.5 1.5 0\nf 1 2 3 5 4\nf 1 2 3\n"
    shape, report = load_mesh(write(tmp_path, "poly.obj", text))
    assert report.triangulated_polygons == 1
    assert shape.n_faces == 4
    faces, n = triangulate([[0, 1, 2, 3], [4, 5, 6], [7, 8, 9, 10, 11]])
    np.testing.assert_array_equal(faces, [[0, 1, 2], [0, 2, 3], [4, 5, 6], [7, 8, 9], [7, 9, 10], [7, 10, 11]])
    assert n == 2


def test_negative_indices_and_unreferenced_vertices(tmp_path):
    text = "v 9 9 9\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 5 5 5\n"
    shape, report = load_mesh(write(tmp_path, "neg.obj", text))
    assert shape.n_vertices == 3 and shape.n_faces == 1
    assert report.dropped_unreferenced_vertices == 2
    np.testing.assert_array_equal(report.vertex_map, [-1, 0, 1, 2, -1])


def test_nan_vertices_drop_their_faces_or_error(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0 0\nv 1 1 inf\nf 1 2 3\nf 2 4 3\nf 1 5 2\n"
    p = write(tmp_path, "nan.obj", text)
    shape, report = load_mesh(p)
    assert shape.n_faces == 1 and report.dropped_nonfinite_faces == 2
    assert np.all(np.isfinite(shape.vertices))
    with pytest.raises(ValueError, match="NaN"):
        load_mesh(p, nonfinite="error")


def test_repeated_index_faces_are_dropped(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 1 2\n"
    shape, report = load_mesh(write(tmp_path, "rep.obj", text))
    assert shape.n_faces == 1 and report.dropped_repeated_index_faces == 1


@pytest.mark.parametrize(
    "name,text,match",
    [
        ("empty.obj", "", "empty"),
        ("novert.obj", "# nothing\n", "no vertices"),
        ("noface.obj", "v 0 0 0\nv 1 0 0\n", "no faces"),
        ("range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n", "references vertex 6"),
        ("zero.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "index 0"),
        ("badnum.obj", "v 0 zero 0\n", "bad vertex"),
        ("short.obj", "v 0 0\n", "3 coordinates"),
        ("badface.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", "bad face index"),
        ("alldeg.obj", "v 0 0 0\nv 1 0 0\nf 1 1 2\n", "no valid faces"),
    ],
)
def test_bad_files_give_clear_errors(tmp_path, name, text, match):
    p = write(tmp_path, name, text)
    with pytest.raises(ValueError, match=match):
        load_mesh(p)


def test_unsupported_and_missing(tmp_path):
    with pytest.raises(ValueError, match="unsupported"):
        load_mesh(write(tmp_path, "x.fbx", "junk"))
    with pytest.raises(ValueError, match="no such file"):
        load_mesh(tmp_path / "missing.obj")
    with pytest.raises(ValueError, match="cannot read"):
        load_mesh(write(tmp_path, "junk.glb", "this is not a glb"))
    from proctex.geometry.meshio import load_mesh_bytes

    with pytest.raises(ValueError, match="x.obj: the file is empty"):
        load_mesh_bytes(b"", "x.obj")
    with pytest.raises(ValueError, match="unsupported"):
        load_mesh_bytes(b"v 0 0 0\n", "x.fbx")
    with pytest.raises(ValueError, match="y.glb: cannot read"):
        load_mesh_bytes(b"this is not a glb", "y.glb")


def test_empty_stl_is_an_error(tmp_path):
    p = tmp_path / "e.stl"
    p.write_text("solid empty\nendsolid empty\n")
    with pytest.raises(ValueError):
        load_mesh(p)


def test_clean_mesh_on_arrays_matches_file_path():
    v, f = two_cubes_touching()
    sv, sf = soup(v, f)
    out_v, out_f, rep = clean_mesh(sv, sf)
    assert connected_parts(out_f, len(out_v))[2] == 2
    assert rep.connectivity == "stitch"


def test_read_obj_ignores_other_statements():
    v, polys = read_obj("o thing\ng grp\nusemtl m\nv 0 0 0 1.0\nv 1 0 0\nv 0 1 0\nvt 0 0\nl 1 2\nf 1/1 2/1 3/1\n")
    assert v.shape == (3, 3) and polys == [[0, 1, 2]]


def test_sofa_loads_with_nine_parts(sofa_dir):
    shape, report = load_mesh(sofa_dir / "train" / "0.obj")
    assert shape.n_vertices == 3538 and shape.n_faces == 7056
    assert n_parts(shape) == 9
    assert report.stitched_edges == 0  # a well-indexed file is left exactly as it is


def test_vectorised_obj_reader_agrees_with_the_line_reader():
    """Triangle files take the numpy path; it gives the line-by-line reader's exact arrays, and
    anything it does not handle (quads, relative indices, tabs, bad tokens) goes to that reader."""
    from proctex.geometry.meshio import _read_obj_triangles, read_obj

    text = "# c\nv 0 0 0\nv 1.5 0 0\nv 0 1 -2e-3\nv 1 1 0\nvt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3/1/1\nf 2//1 4//1 3//1\n"
    fast = _read_obj_triangles(text)
    assert fast is not None
    v, f = fast
    np.testing.assert_array_equal(v, [[0, 0, 0], [1.5, 0, 0], [0, 1, -2e-3], [1, 1, 0]])
    np.testing.assert_array_equal(f, [[0, 1, 2], [1, 3, 2]])
    for other in (
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n",
        "v\t0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n",
        "v 0 0 0 1\nv 1 0 0 1\nv 0 1 0 1\nf 1 2 3\n",
    ):
        assert _read_obj_triangles(other) is None
    assert np.asarray(read_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n")[1]).tolist() == [[0, 1, 2]]
    with pytest.raises(ValueError, match="bad face index"):
        read_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n")
    with pytest.raises(ValueError, match="out of range"):  # saturates int64: the line reader says where
        read_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n")


def test_unique_rows_matches_numpy_unique_on_rows():
    from proctex.geometry.meshio import unique_rows

    rng = np.random.default_rng(0)
    for a in (rng.integers(0, 3, size=(500, 3)).astype(float), rng.normal(size=(200, 2)), np.zeros((1, 3)), rng.integers(0, 2, size=(50, 4))):
        a = np.concatenate([a, a[::3]])  # duplicates
        distinct, inverse = unique_rows(a)
        ref, ref_inv = np.unique(a, axis=0, return_inverse=True)
        assert np.array_equal(distinct, ref) and np.array_equal(inverse, ref_inv.reshape(-1))
        assert np.array_equal(distinct[inverse], a)
    d, inv = unique_rows(np.array([[0.0, 1.0], [-0.0, 1.0]]))
    assert len(d) == 1 and inv.tolist() == [0, 0]  # by value
    assert unique_rows(np.zeros((0, 3)))[0].shape == (0, 3)
    with pytest.raises(ValueError):
        unique_rows(np.zeros(3))


OBJ_CASES = [
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/2 3/3\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1//1 2//1 3//1\n",
    "# a comment with words\no thing\nv 0 0 0\nvt 0 0\nvn 0 0 1\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1/1/1 2/1/1 3/1/1\n",
    "v 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nf 1 2 3\r\n",
    "v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
]
OBJ_DECLINED = [  # the column reader leaves these to the others (a quad, a tab, a relative index, ...)
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3 4\n",
    "v\t0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n",
    "v 0 0 0 1\nv 1 0 0 1\nv 0 1 0 1\nf 1 2 3\n",
    " v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    "vx 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    "v 0  0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    "",
]


def test_the_column_reader_agrees_with_the_numpy_reader_or_declines(sofa_dir):
    """The Arrow column reader of OBJ (the upload fast path) gives exactly the numpy reader's arrays
    on every sofa export and on the hand cases, and declines what it does not take, which the other
    readers then read as before."""
    from proctex.geometry.meshio import _read_obj_columns, _read_obj_triangles

    files = sorted(sofa_dir.rglob("*.obj"))
    texts = [f.read_text() for f in files] + OBJ_CASES
    for text in texts:
        a, b = _read_obj_columns(text), _read_obj_triangles(text)
        assert a is not None and b is not None
        assert np.array_equal(a[0], b[0], equal_nan=True) and np.array_equal(a[1], b[1])
    for text in OBJ_DECLINED:
        assert _read_obj_columns(text) is None
        if text.strip():
            v, polys = read_obj(text)  # still read, by the other paths
            assert len(v) >= 2 and len(polys) == 1
    bad = "v 0 0 x\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    assert _read_obj_columns(bad) is None
    with pytest.raises(ValueError, match="bad vertex coordinates"):
        read_obj(bad)


def test_obj_groups_are_parts_when_asked_and_nothing_joins_across_them():
    """An upload whose pieces share vertices (one connected mesh, as Blender's evaluated mesh of a
    graph that joins its parts) but names its parts as OBJ groups (the add-on's part attribute):
    with ``groups=True`` each group is a part of its own, never stitched to its neighbour."""
    import importlib.util
    from pathlib import Path

    from proctex.geometry.meshio import load_mesh_bytes, read_obj_groups
    from proctex.geometry.parts import segment

    spec = importlib.util.spec_from_file_location("client", Path(__file__).resolve().parents[1] / "clients" / "blender" / "proctex_blender" / "client.py")
    client = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(client)
    # A strip of 4 quads (8 triangles) sharing its inner edges: one component by index.
    verts = [float(x) for i in range(5) for x in (i, 0, 0)] + [float(x) for i in range(5) for x in (i, 1, 0)]
    tris = []
    for i in range(4):
        tris += [i, i + 1, 5 + i, i + 1, 6 + i, 5 + i]
    parts = [0, 0, 0, 0, 1, 1, 2, 2]
    plain, grouped = client.obj_text(verts, tris), client.obj_text(verts, tris, parts)
    assert grouped.count(b"\ng part_") == 3
    assert segment(load_mesh_bytes(plain, "m.obj", groups=True)[0]).n_parts == 1
    shape, report = load_mesh_bytes(grouped, "m.obj", groups=True)
    assert segment(shape).n_parts == 3 and report.connectivity == "index" and shape.n_faces == 8
    assert segment(load_mesh_bytes(grouped, "m.obj")[0]).n_parts == 1  # groups are not parts unless asked
    assert read_obj_groups("v 0 0 0\nf 1 1 1\n", 1) is None
    with pytest.raises(ValueError, match="one value per triangle"):
        client.obj_text(verts, tris, [0])


def test_obj_groups_by_runs_answer_what_the_line_by_line_reading_answers():
    """:func:`read_obj_groups` counts the faces between group lines in whole runs where lines end in
    ``\\n`` or ``\\r\\n``; on files with faces before the first group, repeated and empty groups,
    ``o`` lines, CRLF, a name with spaces, more face lines than polygons, one group only, and line
    breaks only ``str.splitlines`` knows (the line-by-line reading then), it answers what the
    line-by-line reading answers. A file whose group lines it missed would differ: the test can fail."""
    from proctex.geometry.meshio import _obj_groups_by_line, _plain_breaks, read_obj_groups

    def obj(*blocks: str, nl: str = "\n") -> str:
        return nl.join(blocks) + nl

    f3 = "f 1 2 3"
    cases = [
        obj("v 0 0 0", f3, "g seat", f3, f3, "g arm left", f3, "g seat", f3, "o empty", "g back", f3),
        obj("g a", f3, "g b", f3, nl="\r\n"),
        obj("o one", f3, f3),  # one group: None
        obj("g a", f3, "g b", f3, "g c"),  # a last group with no face
        obj("g a", f3, "g b", f3, f3),  # three face lines, two polygons asked for below
        obj("g a", f3) + "g b\x0bf 1 2 3\n",  # a vertical tab breaks lines for splitlines only
        "g a\rf 1 2 3\rg b\rf 1 2 3\r",  # old Mac breaks
    ]
    polygons = [6, 2, 2, 2, 2, 2, 2]
    for text, n in zip(cases, polygons):
        expected = _obj_groups_by_line(text, n)
        got = read_obj_groups(text, n)
        assert (got is None) == (expected is None), text
        if expected is not None:
            np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(read_obj_groups(cases[0], 6), [0, 1, 1, 2, 1, 3])
    assert _plain_breaks(cases[1]) and not _plain_breaks(cases[5]) and not _plain_breaks(cases[6])
    assert not _plain_breaks("g a\u2028f 1 2 3\n")


def _numbers(rnd) -> str:
    """A random decimal as exporters and people write them: fixed, scientific, integers, signs,
    leading zeros, negative zero, and lengths at and past the compiled reader's exact range."""
    kind = rnd.randrange(9) if rnd.random() < 0.05 else rnd.choice([0, 2, 3, 8])  # the edges (17 digits, 2**53, 10**22) now and then
    x = rnd.uniform(-1, 1) * 10 ** rnd.randint(-8, 8)
    if kind == 0:
        return f"{x:.6f}"
    if kind == 1:
        return repr(x)
    if kind == 2:
        return f"{x:.{rnd.randint(0, 12)}e}".replace("e+0", "e").replace("e-0", "e-")
    if kind == 3:
        return str(rnd.randint(-(10**6), 10**6))
    if kind == 4:
        return rnd.choice(["-0.000000", "0", "-0", "00.5", "1.", ".5", "-.25", "1E5", "2e+3", "1e22", "1e23", "1e-22", "1e-23"])
    if kind == 5:
        return str(rnd.randint(10**15, 10**19)) + rnd.choice(["", ".0", ".5"])  # about 2**53 and past 18 digits
    if kind == 6:
        return "0." + "".join(rnd.choice("0123456789") for _ in range(rnd.randint(10, 20)))
    if kind == 7:
        return f"{x:.17g}"
    return f"{x:.3f}"


def _random_obj(rnd, plain: bool) -> str:
    """A random OBJ: triangles with ``a``, ``a/b``, ``a//c``, ``a/b/c`` corners, group lines
    (repeated, empty-named, spaced), comments, ``vt``/``vn``/``s``/``usemtl`` lines, empty lines, LF
    or CRLF; unless ``plain``, one line of a kind the compiled reader declines (a quad, a tab, a
    relative index, an extra column, a non-ASCII name, a lone CR, a bare tag, ``nan``)."""
    n_v = rnd.randint(3, 12)
    lines = [f"v {_numbers(rnd)} {_numbers(rnd)} {_numbers(rnd)}" for _ in range(n_v)]
    for _ in range(rnd.randint(1, 20)):
        kind = rnd.randrange(6)
        if kind < 3:
            c = [rnd.randint(1, n_v) for _ in range(3)]
            form = rnd.choice(["{}", "{}/1", "{}//2", "{}/3/4"])
            lines.append("f " + " ".join(form.format(i) for i in c))
        elif kind == 3:
            lines.append(rnd.choice(["g seat", "o arm left", "g ", "g seat", "o  back  ", "g x"]))
        elif kind == 4:
            lines.append(rnd.choice(["# note", "vt 0.5 0.5", "vn 0 0 1", "s off", "usemtl m", "", "l 1 2"]))
        else:
            lines.insert(rnd.randrange(len(lines)), f"v {_numbers(rnd)} {_numbers(rnd)} {_numbers(rnd)}")
    if not plain:
        odd = rnd.choice(["f 1 2 3 1", "f\t1 2 3", "f -1 -2 -3", "v 1 2 3 4", "g s\u00e9at", "v 1\r2 3", "v", "v nan 0 0", "f 1 2 0", "v 1  2 3", "vx 1 2 3", "p 1"])
        lines.insert(rnd.randrange(len(lines) + 1), odd)
    nl = rnd.choice(["\n", "\r\n"])
    return nl.join(lines) + rnd.choice(["", nl])


def test_the_compiled_obj_reader_agrees_with_the_other_readers_or_declines(sofa_dir):
    """The compiled reader of plain OBJ (:mod:`proctex.geometry.obj_kernels`, every OBJ upload)
    gives the other readers' exact vertex bits, faces and groups on every sofa export and on 600
    random files of plain and odd lines, and declines (None) what it does not take, which those
    readers then answer as before. The random numbers include the edges of its exact range (2**53,
    18 digits, 10**22); a reader that multiplied by an inexact 10**-k instead of dividing by an
    exact 10**k would differ on them: the test can fail (checked below)."""
    import random

    from proctex.geometry.meshio import plain_obj_groups, read_obj_groups
    from proctex.geometry.obj_kernels import read_plain

    rnd = random.Random(11)
    texts = [f.read_text() for f in sorted(sofa_dir.rglob("*.obj"))[:20]] + [_random_obj(rnd, plain=i % 3 != 0) for i in range(600)]
    taken = declined = 0
    taken_texts: list[str] = []
    for text in texts:
        got = read_plain(text.encode())
        try:
            v, polys = read_obj(text)
        except ValueError:  # a file the others refuse (face index 0) is never taken
            assert got is None, text
            declined += 1
            continue
        if got is None:
            declined += 1
            continue
        taken += 1
        taken_texts.append(text)
        gv, gf, fg, names = got
        assert gv.dtype == np.float64 and gf.dtype == np.int64
        # margin: none, bit-equal natively and under tests.portable (AVX-512 off): the reader only
        # adds integers and makes one correctly rounded multiplication or division per number
        assert np.array_equal(gv.view(np.int64), np.asarray(v, dtype=np.float64).view(np.int64)), text
        assert np.array_equal(gf, np.asarray(polys)), text
        expected = read_obj_groups(text, len(polys))
        mine = plain_obj_groups(fg, names)
        assert (mine is None) == (expected is None), text
        if expected is not None:
            np.testing.assert_array_equal(mine, expected)
    assert taken > 250 and declined > 150  # 301 and 319 with this seed
    for odd in (
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 1\n",
        "v 0 0 0\nv 1 0 0\nv 0 1.0000000000000000001 0\nf 1 2 3\n",
        "o s\xe9at\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        "v 0 0 1e23\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    ):
        assert read_plain(odd.encode()) is None
        assert len(read_obj(odd)[0]) == 3  # the other readers still answer
    # The wrong method (times an inexact 10.0**-k) gives other bits on numbers of the taken files.
    from decimal import Decimal

    def times_inexact(token: str) -> float:
        sign, digits, exp = Decimal(token).as_tuple()
        m = float(int("".join(map(str, digits)) or "0"))
        return (-1.0 if sign else 1.0) * m * 10.0**exp

    tokens = [t for text in taken_texts for line in text.splitlines() if line.startswith("v ") for t in line.split()[1:]]
    assert sum(times_inexact(t) != float(t) for t in tokens) > 100  # 1,050 of 7,467


def test_a_plain_obj_loads_the_same_with_and_without_the_compiled_reader(sofa_dir, monkeypatch):
    """``load_mesh_bytes`` of sofa exports and of a grouped upload gives the same shape (bits,
    faces, parts) through the compiled reader as through the others (numba missing), and the
    header counts agree."""
    import sys

    import proctex.geometry.meshio as meshio
    from proctex.geometry.meshcounts import declared_counts
    from proctex.geometry.parts import segment

    grouped = b"g a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\ng b\nf 2 4 3\ng a\nf 1 3 4\n"
    datas = [f.read_bytes() for f in sorted(sofa_dir.rglob("*.obj"))[:6]] + [grouped]
    fast = [meshio.load_mesh_bytes(d, "m.obj", groups=True)[0] for d in datas]
    counted = [declared_counts(d, "obj") for d in datas]
    monkeypatch.setitem(sys.modules, "proctex.geometry.obj_kernels", None)  # its import raises ImportError
    assert meshio._read_plain_obj(datas[0]) is None
    assert [declared_counts(d, "obj") for d in datas] == counted  # by the array passes now
    slow = [meshio.load_mesh_bytes(d, "m.obj", groups=True)[0] for d in datas]
    for a, b in zip(fast, slow):
        # margin: none, bit-equal natively and under tests.portable (AVX-512 off)
        assert np.array_equal(a.vertices.view(np.int64), b.vertices.view(np.int64)) and np.array_equal(a.faces, b.faces)
        assert segment(a).n_parts == segment(b).n_parts
    assert segment(fast[-1]).n_parts == 2 and fast[-1].n_faces == 3


def test_the_boundary_check_answers_what_counting_answers():
    """:func:`proctex.geometry.meshio._has_single` (one sort) says whether a value occurs once, as
    ``np.unique``'s counts do, on random keys with and without singles and on tiny arrays."""
    from proctex.geometry.meshio import _has_single

    rng = np.random.default_rng(3)
    for trial in range(300):
        keys = rng.integers(0, rng.integers(1, 40), size=rng.integers(0, 60))
        if trial % 2:
            keys = np.concatenate([keys, keys])  # every value twice at least: no single
        _, counts = np.unique(keys, return_counts=True)
        assert _has_single(keys) == bool((counts == 1).any())
