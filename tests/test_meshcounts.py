"""Limits checked from a mesh file's header before any parse (issue 34): the declared counts agree
with what the parsers read on real files, and hostile files (a 2M-face PLY, an OBJ face of 100,000
corners, a glTF node chain 1,000 deep, a node cycle) are refused in milliseconds."""

from __future__ import annotations

import base64
import json
import struct
import time

import numpy as np
import pytest

from proctex.geometry.meshcounts import MAX_NODE_DEPTH, declared_counts
from proctex.geometry.meshio import load_mesh_bytes
from proctex.models import get_model


def chain_gltf(depth: int, cycle: bool = False) -> bytes:
    """A self-contained .gltf: one triangle under a chain of ``depth`` nodes, each moving it up by 1."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32).tobytes()
    i = np.array([0, 1, 2], np.uint16).tobytes() + b"\0\0"
    buf = v + i
    nodes = [{"children": [k + 1], "translation": [0, 0, 1]} for k in range(depth - 1)] + [{"mesh": 0, "translation": [0, 0, 1]}]
    if cycle:
        nodes[-1]["children"] = [0]
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": nodes,
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"byteLength": len(buf), "uri": "data:application/octet-stream;base64," + base64.b64encode(buf).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 6}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}, {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}],
    }
    return json.dumps(doc).encode()


def test_declared_counts_agree_with_the_parsers_on_real_files(sofa_dir):
    import trimesh

    sofa = (sofa_dir / "train" / "0.obj").read_bytes()
    c = declared_counts(sofa, "obj")
    text = sofa.decode()
    assert c.vertices == sum(line.startswith("v ") for line in text.splitlines())
    assert c.triangles == sum(len(line.split()) - 3 for line in text.splitlines() if line.startswith("f "))
    mug = get_model("mug").generate()
    m = trimesh.Trimesh(mug.vertices, mug.faces, process=False)
    for fmt in ("ply", "stl", "glb"):
        data = m.export(file_type=fmt)
        data = data.encode() if isinstance(data, str) else data
        c = declared_counts(data, fmt)
        assert c.triangles == mug.n_faces, fmt
        if fmt != "stl":  # an STL states triangles only
            assert c.vertices == mug.n_vertices, fmt
    ascii_stl = m.export(file_type="stl_ascii")
    assert declared_counts(ascii_stl.encode() if isinstance(ascii_stl, str) else ascii_stl, "stl").triangles == mug.n_faces


def test_a_chain_within_the_depth_loads_as_the_transforms_say():
    data = chain_gltf(20)
    c = declared_counts(data, "gltf")
    assert (c.depth, c.nodes, c.vertices, c.triangles) == (20, 20, 3, 1)
    shape, _ = load_mesh_bytes(data, "chain.gltf")
    assert np.allclose(sorted(shape.vertices[:, 2]), [20, 20, 20])  # 20 translations of 1, composed


@pytest.mark.parametrize(
    "data, fmt, message",
    [
        (chain_gltf(1000), "gltf", "deep"),
        (chain_gltf(MAX_NODE_DEPTH + 1), "gltf", "deep"),
        (chain_gltf(MAX_NODE_DEPTH), "gltf", None),
        (chain_gltf(5, cycle=True), "gltf", "cycle|twice"),
    ],
)
def test_hostile_node_trees_are_refused_before_any_library_walks_them(data, fmt, message):
    if message is None:  # the deepest tree allowed is read, to the exact boundary
        assert declared_counts(data, fmt).depth == MAX_NODE_DEPTH
        assert load_mesh_bytes(data, "deepest.gltf")[0].n_faces == 1
        return
    t = time.perf_counter()
    with pytest.raises(ValueError, match=message):
        load_mesh_bytes(data, "hostile.gltf")
    assert time.perf_counter() - t < 5  # milliseconds in practice: trimesh never sees it


def test_the_service_refuses_what_a_header_declares_over_its_limits(painted_mug_root):
    from proctex.serve.service import BadInput, FamilyService, Limits, TooLarge
    from proctex.store.layout import FamilyStore

    svc = FamilyService(FamilyStore(painted_mug_root / "mug"), limits=Limits(max_faces=50_000))
    ply = (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000\nproperty float x\nproperty float y\nproperty float z\n"
        b"element face 2000000\nproperty list uchar int vertex_indices\nend_header\n"
    ) + b"\0" * 1000
    huge_face = b"".join(f"v {k} {k % 7} 0\n".encode() for k in range(100)) + b"f " + b" ".join(str(1 + k % 100).encode() for k in range(100_000)) + b"\n"
    binary_stl = b"\0" * 80 + struct.pack("<I", 60_000) + b"\0" * (50 * 60_000)
    for data, name, message in ((ply, "m.ply", "declares 1000000 vertices"), (binary_stl, "m.stl", "declares 60000 faces")):
        with pytest.raises(TooLarge, match=message):
            svc.shape_from_mesh(data, name)
    with pytest.raises(BadInput, match="a face of 100000 corners"):
        svc.shape_from_mesh(huge_face, "m.obj")
    big_cap = b"".join(f"v {np.cos(a)} {np.sin(a)} 0\n".encode() for a in np.linspace(0, 2 * np.pi, 512, endpoint=False))
    assert svc.shape_from_mesh(big_cap + b"f " + b" ".join(str(k + 1).encode() for k in range(512)) + b"\n", "cap.obj").n_faces == 510
    with pytest.raises(BadInput, match="deep"):
        svc.shape_from_mesh(chain_gltf(100), "m.gltf")
    ok = svc.shape_from_mesh(chain_gltf(3), "m.gltf")  # within the limits it is read
    assert ok.n_faces == 1


def _with_accessor(data: bytes, index: int, **change) -> bytes:
    """The GLB ``data`` with accessor ``index``'s fields changed (None: removed)."""
    n = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20 : 20 + n])
    for k, v in change.items():
        if v is None:
            doc["accessors"][index].pop(k, None)
        else:
            doc["accessors"][index][k] = v
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    out = data[:12] + struct.pack("<I", len(js)) + b"JSON" + js + data[20 + n :]
    return out[:8] + struct.pack("<I", len(out)) + out[12:]


@pytest.mark.parametrize(
    "change, message",
    [
        ({"count": -3}, "count -3"),
        ({"count": 0}, "count 0"),
        ({"count": 1.5}, "count 1.5"),
        ({"count": "7"}, 'count "7"'),
        ({"count": True}, "count true"),
        ({"count": None}, "count null"),
        ({"count": 10**12}, "past the end of bufferView"),
        ({"byteOffset": -4}, "byteOffset -4"),
        ({"componentType": 5127}, "componentType 5127"),
        ({"bufferView": 99}, "bufferView 99"),
    ],
)
def test_a_glb_whose_index_accessor_lies_is_refused_not_read_short(change, message):
    """An index accessor with ``count: -3`` was read as all but the last three indices (a triangle
    dropped, the mesh served); every accessor's count, type, offset and reach is checked before a
    library reads it, and the file is refused naming the accessor."""
    from proctex.texture.export import glb_bytes

    mug = get_model("mug").generate()
    data = glb_bytes(mug.vertices, mug.faces, np.zeros((len(mug.faces), 3, 2)), np.zeros(len(mug.faces), np.int64), [np.zeros((8, 8, 3), np.uint8)])
    n = struct.unpack_from("<I", data, 12)[0]
    indices = json.loads(data[20 : 20 + n])["meshes"][0]["primitives"][0]["indices"]
    shape, _ = load_mesh_bytes(data, "m.glb")
    assert len(shape.faces) == len(mug.faces)  # the file as written reads whole
    bad = _with_accessor(data, indices, **change)
    with pytest.raises(ValueError, match=f"accessor {indices} .*{message}".replace("(", r"\(").replace(")", r"\)")):
        load_mesh_bytes(bad, "m.glb")


def test_obj_counts_by_columns_answer_what_the_line_reading_answers():
    """The OBJ header count by array passes equals the line-by-line regex reading on random files
    built from vertex, face (1 to 9 corners, blanks of every kind between them), comment, normal
    and empty lines with LF or CRLF endings; files it does not take (a line starting with a blank,
    a lone CR) are left to the line reading. A count that took ``vn`` lines for vertices, or a
    ``\\x0b`` for a line break, would differ: the test can fail."""
    import random

    from proctex.geometry.meshcounts import _obj_counts_by_columns, _obj_counts_by_lines

    rnd = random.Random(7)
    blanks = [" ", "  ", "\t", " \t", "\x0b", "\x0c "]
    taken = 0
    for trial in range(300):
        lines = []
        for _ in range(rnd.randint(0, 40)):
            kind = rnd.choice(["v", "f", "vn", "#", "", "o", "ff", "f\x0b"])
            if kind == "f":
                lines.append("f" + rnd.choice(blanks[:4]) + rnd.choice(blanks).join(str(rnd.randint(1, 9)) for _ in range(rnd.randint(1, 9))) + rnd.choice(["", " ", "\t"]))
            elif kind == "v":
                lines.append("v" + rnd.choice(blanks[:4]) + " ".join("0.5" for _ in range(3)))
            else:
                lines.append(kind + " 1 2" if kind else "")
        if trial % 10 == 0 and lines:
            lines[rnd.randrange(len(lines))] = " v 1 2 3"
        text = rnd.choice(["\n", "\r\n"]).join(lines) + rnd.choice(["", "\n"])
        if trial % 15 == 0:
            text += "v 1 2 3\rf 1 2 3"
        data = text.encode()
        fast = _obj_counts_by_columns(data)
        v, corners = _obj_counts_by_lines(data)
        if fast is None:
            assert " v" in text or "\r" in text.replace("\r\n", "") or not data
            continue
        taken += 1
        assert fast[0] == v and list(fast[1]) == corners, text
    assert taken > 200
    assert _obj_counts_by_columns(b"vn 1 2 3\nv 1 2 3\nf 1\x0b2 3\n")[0] == 1


def test_the_compiled_obj_count_answers_what_the_line_reading_answers(sofa_dir):
    """The compiled count of a plain OBJ (:func:`proctex.geometry.obj_kernels.plain_counts`, the
    first thing an OBJ upload meets) gives the line reading's vertices, triangles and largest face
    on every sofa export and on random files of vertex, face (1 to 9 corners, one or more spaces
    between them, a trailing space), comment, normal, group and empty lines, LF or CRLF, and
    declines (None) a file with a tab, a ``\x0b``, a lone CR, a line starting with a blank or an
    unknown tag. A count that took ``vn`` lines for vertices, or counted a face's spaces instead of
    its corners, would differ: the test can fail."""
    import random

    from proctex.geometry.meshcounts import _obj_counts, _obj_counts_by_lines
    from proctex.geometry.obj_kernels import plain_counts

    def by_lines(data: bytes) -> tuple[int, int, int]:
        v, corners = _obj_counts_by_lines(data)
        return v, sum(max(c - 2, 0) for c in corners), max(corners, default=3)

    rnd = random.Random(8)
    datas = [f.read_bytes() for f in sorted(sofa_dir.rglob("*.obj"))[:10]]
    for trial in range(300):
        lines = []
        for _ in range(rnd.randint(0, 40)):
            kind = rnd.choice(["v", "f", "f", "vn", "#", "", "o", "g"])
            if kind == "f":
                lines.append("f " + rnd.choice([" ", "  "]).join(str(rnd.randint(1, 9)) for _ in range(rnd.randint(1, 9))) + rnd.choice(["", " "]))
            elif kind == "v":
                lines.append("v 0.5 0.5 0.5")
            else:
                lines.append(kind + " 1 2" if kind else "")
        if trial % 5 == 0 and lines:
            lines[rnd.randrange(len(lines))] = rnd.choice([" v 1 2 3", "f 1\t2 3", "f 1\x0b2 3", "x 1", "v 1 2\r3"])
        datas.append((rnd.choice(["\n", "\r\n"]).join(lines) + rnd.choice(["", "\n"])).encode())
    taken = 0
    for data in datas:
        fast = plain_counts(data)
        if fast is None:
            assert any(c in data for c in (b" v", b"\t", b"\x0b", b"x 1", b"2\r3")), data
            continue
        taken += 1
        assert fast == by_lines(data) == _obj_counts(data), data  # integer counts: exact on any CPU (also under tests.portable)
    assert taken > 200
    assert plain_counts(b"vn 1 2 3\nv 1 2 3\nf 1  2 3 \n") == (1, 1, 3)
