"""Part names read from a Geometry Nodes tree (issue 50): the producer of every face, the names its
frames and node groups give it, the file's values as defaults. The pure naming rules are tested on
hand-made producer records; the Blender side on the bench fixture built in code (frames, nested
frames and groups, instances, a swept curve, a join under one frame, unnamed defaults) and on the
handed-out files where they exist."""

from __future__ import annotations

import json

import numpy as np
import pytest

from proctex.sources.provenance import (
    is_computation,
    is_default,
    label_words,
    matchable_words,
    model_words,
    part_names,
    producer_names,
    same_word,
)

from .test_blender import REAL, blends, needs_bpy  # noqa: F401  (blends: the fixture files, built once per module)


# ------------------------------------------------------------------------------------- the rules
def test_label_words_split_camel_case_and_drop_numbering():
    assert label_words("CabinetBoardRight.002") == ["Cabinet", "Board", "Right"]
    assert label_words("Back_Rest-2") == ["Back", "Rest"]
    assert label_words("LSeat") == ["L", "Seat"] and label_words("") == [] and label_words("123.004") == []


@pytest.mark.parametrize(
    "label,bl_label,default",
    [
        ("Cube.001", "Cube", True),
        ("Frame.006", "", True),
        ("Mesh Line.003", "Mesh Line", True),
        ("NodeGroup", "", True),
        ("Plane", "", True),
        ("Seat", "", False),
        ("Cube Seat", "Cube", False),
        ("Legs.001", "", False),
    ],
)
def test_default_names_are_told_from_an_authors(label, bl_label, default):
    assert is_default(label, bl_label) is default


@pytest.mark.parametrize(
    "label,computation",
    [
        ("Center Z at Origin", True),
        ("SetToZeroZAxis", True),
        ("Spawn Leaves", True),
        ("Determine Trunk area", True),
        ("Meshing The Curve", True),
        ("EverGreenBasedOnSurface", True),
        ("Back Rest", False),
        ("Dividing Boards", False),
        ("Sliding Door", False),
        ("Left Arm", False),
        ("Legs", False),
    ],
)
def test_labels_of_computations_are_not_part_names(label, computation):
    assert is_computation(label_words(label)) is computation


def test_a_producer_takes_its_most_specific_meaningful_label():
    """Node label, then a renamed node, the object an Info node reads, frames inside out, groups
    inside out; defaults, computations and the model's own words are passed over and listed."""
    whole = model_words("Cabinet", "Geometry Nodes")
    producers = [
        {
            "id": 1,
            "node": "Cube.003",
            "label": "",
            "type": "GeometryNodeMeshCube",
            "bl_label": "Cube",
            "frames": [{"name": "Frame.002", "label": "Center Z at Origin"}, {"name": "Frame", "label": "Handles"}],
            "groups": [{"node": "Group", "label": "", "tree": "Doors"}],
        },
        {"id": 2, "node": "Knob", "label": "", "type": "GeometryNodeMeshUVSphere", "bl_label": "UV Sphere", "frames": [], "groups": []},
        {"id": 3, "node": "Cube", "label": "Top Panel", "type": "GeometryNodeMeshCube", "bl_label": "Cube", "frames": [], "groups": []},
        {"id": 4, "node": "Object Info", "type": "GeometryNodeObjectInfo", "bl_label": "Object Info", "data": "Leaf", "frames": [], "groups": []},
        {"id": 5, "node": "Cube", "type": "GeometryNodeMeshCube", "bl_label": "Cube", "frames": [], "groups": [{"node": "Group.001", "label": "", "tree": "CabinetBoardRight"}]},
        {
            "id": 6,
            "node": "Cube",
            "type": "GeometryNodeMeshCube",
            "bl_label": "Cube",
            "frames": [{"name": "Frame.001", "label": ""}],
            "groups": [{"node": "Group.002", "label": "", "tree": "Cabinet"}],
        },
        {"id": 7, "node": "Group Input", "type": "NodeGroupInput", "bl_label": "Group Input", "data": "Cabinet", "frames": [], "groups": []},
        # a group left at a default name inside a frame "Arms" of its parent tree: the frame names it
        {
            "id": 8,
            "node": "Cube",
            "type": "GeometryNodeMeshCube",
            "bl_label": "Cube",
            "frames": [],
            "groups": [
                {"node": "Group.004", "label": "", "tree": "NodeGroup.002", "frames": [{"name": "Frame.003", "label": "Arms"}]},
                {"node": "Group.005", "label": "", "tree": "Furniture", "frames": []},
            ],
        },
        "not a record",
        {"id": True},
    ]
    names = producer_names(producers, whole)
    assert {i: n.name for i, n in names.items()} == {1: "Handles", 2: "Knob", 3: "Top Panel", 4: "Leaf", 5: "Board Right", 6: "", 7: "", 8: "Arms"}
    assert names[1].where == "frame" and ("Center Z at Origin", "labels a computation") in names[1].dropped
    assert ("Cube.003", "a default name") in names[1].dropped
    assert names[5].where == "group" and names[6].dropped[-1] == ("Cabinet", "names the whole model")
    long = producer_names([{"id": 1, "node": "x" * 500 + " y", "type": "T", "frames": [], "groups": []}])[1]
    assert len(long.name) <= 64


def test_a_part_takes_the_name_covering_most_of_its_area_and_lists_the_others():
    names = producer_names([{"id": 1, "node": "Seat"}, {"id": 2, "node": "Cushion"}, {"id": 3, "node": "Cube.001", "bl_label": "Cube"}])
    source = np.array([1, 2, 2, 0, 3, 1])
    part = np.array([0, 0, 0, 1, 1, 2])
    areas = np.array([3.0, 1.0, 1.0, 1.0, 1.0, np.nan])
    got = part_names(source, part, areas, names, 3)
    assert got.names == ["Seat", "", "Seat"] and got.others == [["Cushion"], [], []]
    assert got.covered == pytest.approx(6.0 / 7.0)  # the face without a producer has 1 of 7 (the NaN area counts 0)
    with pytest.raises(ValueError, match="must be"):
        part_names(source, part[:3], areas, names, 3)
    with pytest.raises(ValueError, match="outside"):
        part_names(source, part, areas, names, 2)


def test_prompt_words_match_a_names_words_up_to_plurals_never_qualifiers():
    assert matchable_words("Left Arm") == ["arm"] and matchable_words("Board Right") == ["board"]
    assert matchable_words("L Seat") == ["seat"] and matchable_words("Cabinet Shelf", model_words("Cabinet")) == ["shelf"]
    assert same_word("shelf", "shelves") and same_word("arms", "arm") and same_word("body", "bodies") and not same_word("seat", "set")


# ------------------------------------------------------------------------------------ in Blender
@needs_bpy
def test_the_bench_parts_carry_the_names_its_node_tree_gives_them(blends):
    """Frames (the innermost of two nested frames), nested node groups (the innermost), a curve swept
    into a mesh, instances and a join under one frame give the names; a frame labelling a
    computation and default names give none; every face has a producer."""
    from proctex.geometry.parts import analyse, segment
    from proctex.sources.blender import BlenderModel

    model = BlenderModel(blends / "bench.blend", "Bench")
    try:
        shape = model.generate({})
        seg = segment(shape)
        got = sorted(p.label for p in seg.parts)
        assert got == ["", "", "Back Rest", "Legs", "Legs", "Legs", "Legs", "Rail", "Seat", "Seat"]
        assert model.last_names.covered == 1.0
        dropped = {lab: why for n in model.producer_names.values() for lab, why in n.dropped}
        assert dropped["Center Z at Origin"] == "labels a computation"
        assert all(n.name != "Supports" for n in model.producer_names.values())  # the inner frame "Legs" is nearer
        assert {g.label for g in analyse(shape).groups} >= {"Seat", "Legs", "Back Rest", "Rail"}
        no_back = model.generate({"Has Back": False, "Legs": 2})
        assert sorted(p.label for p in segment(no_back).parts).count("Legs") == 2 and "Back Rest" not in no_back.label_names
    finally:
        model.close()


@needs_bpy
def test_the_file_values_are_the_defaults_and_an_unranged_input_is_held(blends):
    from proctex.sources.blender import BlenderModel

    model = BlenderModel(blends / "bench.blend", "Bench")
    try:
        d = model.space.defaults()
        assert d == {"Width": 1.2, "Legs": 4, "Leg Height": 0.45, "Has Back": True, "Seat Size": 0.4}
        assert model.plan.fixed == {"Seat Size": 0.4} and model.space["Seat Size"].low == model.space["Seat Size"].high == 0.4
    finally:
        model.close()
    listed = BlenderModel(blends / "bench.blend", "Bench", bounds={"Width": [1.0, 1.5]}, listed=["Has Back"])
    try:
        assert set(listed.plan.fixed) == {"Legs", "Leg Height", "Seat Size"}
        assert all(p["Legs"] == 4 and p["Leg Height"] == 0.45 for p in listed.space.sample(4, seed=1))
    finally:
        listed.close()


@needs_bpy
def test_provenance_tells_instances_apart_and_keeps_each_producers_own_box(blends):
    """Each realized leg has its own instance index; the seat board, scaled by Width, keeps its box
    coordinates (each vertex at a corner of its own box) whatever the width: a known truth."""
    from proctex.sources.blender import BlenderSession

    session = BlenderSession(blends / "bench.blend", "Bench")
    try:
        ids = {p["id"]: p for p in session.producers}
        board = next(i for i, p in ids.items() if p["node"] == "Cube" and p["frames"] and p["frames"][0]["label"] == "Seat")
        leg = next(i for i, p in ids.items() if p["type"] == "GeometryNodeMeshCylinder")
        boxes = []
        for width in (0.8, 2.0):
            out = session.generate({"Width": width})
            legs = out.face_source == leg
            assert sorted(np.unique(out.face_instance[legs]).tolist()) == [0, 1, 2, 3]
            assert (out.face_instance[~legs & (out.face_source > 0)] == -1).all()  # nothing else was instanced
            verts = np.unique(out.faces[out.face_source == board])
            assert len(verts) == 8
            box = out.canonical[verts]
            assert np.allclose(box, np.round(box), atol=1e-6)  # corners of its own unit box
            order = np.lexsort(out.vertices[verts].T)
            boxes.append(box[order])
            assert np.isclose(np.ptp(out.vertices[verts][:, 0]), width, atol=1e-6)
        assert np.array_equal(boxes[0], boxes[1])
    finally:
        session.close()


def _objects():
    """Every handed-out object with a Geometry Nodes modifier, and the fixtures'."""
    real = [("chair.blend", "Cube"), ("table.blend", "Cube"), ("cabinet.blend", "Cabinet"), ("lowpoly_trees.blend", "Italian Cypres"), ("lowpoly_trees.blend", "Trees Set one")]
    return [("fixture", f, o) for f, o in (("vase.blend", "Vase"), ("table.blend", "Table"), ("rack.blend", "Rack"), ("bench.blend", "Bench"))] + [("real", f, o) for f, o in real]


@needs_bpy
@pytest.mark.slow
@pytest.mark.parametrize("where,file,obj", _objects())
def test_instrumented_and_plain_evaluation_give_the_same_mesh(blends, where, file, obj):
    """Instrumenting only adds attributes: at the file's values and at two settings drawn from the
    inputs that vary, the vertices and faces are bit-identical to the plain tree's; the share of
    faces with a producer is reported (every face of these files has one)."""
    from proctex.sources.blender import BlenderModel

    path = (blends if where == "fixture" else REAL) / file
    if not path.is_file():
        pytest.skip("the shared .blend files are absent")
    spec = REAL / f"sp_{path.stem}.json"
    listed = None
    bounds = {}
    if where == "real" and spec.is_file():
        from proctex.params import read_params_spec

        read = read_params_spec(spec)
        bounds, listed = read.bounds, sorted(read.kinds)
    model = BlenderModel(path, obj, bounds=bounds, listed=listed)
    try:
        settings = [{}] + ([] if "trees" in file else model.space.sample(2, seed=3))
        for params in settings:
            values = {**model.pins, **model.space.validate(params)}
            fancy = model.session.generate(values)
            plain = model.session.generate(values, plain=True)
            assert np.array_equal(fancy.vertices, plain.vertices) and np.array_equal(fancy.faces, plain.faces), (file, obj, params)
            assert plain.face_source is None and fancy.face_source is not None
            share = float((fancy.face_source > 0).mean())
            print(f"{file}/{obj}: {len(fancy.faces)} faces, {100 * share:.1f} % with a producer")
            assert share == 1.0
    finally:
        model.close()


@pytest.mark.slow  # over 15 s: not in make test's second pass (tests/suite.py)
@needs_bpy
def test_the_parts_and_inputs_commands_show_names_and_file_values(blends, capsys):
    from proctex.cli import main

    assert main(["parts", str(blends / "bench.blend"), "--object", "Bench", "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert sorted(p["name"] for p in got["parts"]) == ["", "", "Back Rest", "Legs", "Legs", "Legs", "Legs", "Rail", "Seat", "Seat"]
    assert got["covered"] == 1.0 and abs(sum(p["area_share"] for p in got["parts"]) - 1.0) < 1e-3
    knob = next(p for p in got["producers"] if p["node"].startswith("Ico Sphere"))
    assert knob["name"] == "" and ["Center Z at Origin", "labels a computation"] in knob["dropped"]
    assert main(["parts", str(blends / "bench.blend"), "--object", "Bench", "--params", '{"Legs": 2}']) == 0
    assert sum(line.startswith("part") and " Legs " in line for line in capsys.readouterr().out.splitlines()) == 2
    for bad, message in (('{"Nope": 1}', "unknown parameters"), ("[1]", "JSON object"), ("{", "not valid JSON"), ('{"Legs": 99}', "Legs")):
        assert main(["parts", str(blends / "bench.blend"), "--object", "Bench", "--params", bad]) == 2
        assert message in capsys.readouterr().err
    assert main(["inputs", str(blends / "bench.blend"), "--object", "Bench", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)["inputs"]}
    assert rows["Width"]["value"] == 1.2 and rows["Width"]["default"] == 1.0 and not rows["Width"]["fixed"]
    assert rows["Seat Size"]["fixed"] and rows["Seat Size"]["value"] == 0.4 and rows["Legs"]["value"] == 4
    assert main(["inputs", str(blends / "bench.blend"), "--object", "Bench"]) == 0
    assert "the node tree names parts: Back Rest, Seat, Legs, Rail" in capsys.readouterr().out


@needs_bpy
def test_a_spec_listing_fewer_inputs_builds_and_its_misspelt_keys_are_named(tmp_path, capsys):
    """The real chair with a spec that lists four inputs (one condition key misspelt): the others
    are held at the file's values, the misspelling is read as the key it is near and said so, an
    unknown key is named with the closest known one."""
    from proctex.store.config import BuildConfig

    if not (REAL / "chair.blend").is_file():
        pytest.skip("the shared .blend files are absent")
    spec = {
        "class_name": "chair",
        "colour": "red",
        "params": {
            "Seat": {
                "type": "nested",
                "params": {
                    "Seat Height": {"type": "float", "range": [0.4, 0.8]},
                    "Seat Width": {"type": "float", "range": [0.4, 0.8]},
                    "Has Arms": {"type": "bool"},
                    "Arm Height": {"type": "float", "range": [0.1, 0.3], "or_dependcies": ["Has Arms"]},
                    "Legs Type": {"type": "int", "range": [0, 2]},
                    "Bottom Size Scale": {"type": "float", "range": [0.7, 1.0], "or_dependencies": [["Legs Type", 1]]},
                },
            }
        },
    }
    path = tmp_path / "sp_small.json"
    path.write_text(json.dumps(spec))
    cfg = BuildConfig.from_dict({"source": {"blender": {"file": str(REAL / "chair.blend"), "object": "Cube"}, "params_spec": str(path)}})
    err = capsys.readouterr().err
    assert "read key 'or_dependcies' as 'or_dependencies'" in err and "'colour' was not understood" in err
    names = ["Arm Height", "Bottom Size Scale", "Has Arms", "Legs Type", "Seat Height", "Seat Width"]
    assert any("or_dependcies" in n for n in cfg.source.spec_notes) and cfg.to_dict()["source"]["listed"] == names
    model = cfg.procedural_model()
    varying = [s.name for s in model.space.specs if s.name not in model.plan.fixed]
    assert sorted(varying) == names
    # the file holds Bottom Size Scale 0.5, outside the spec's [0.7, 1]: its default is clamped, and said so
    assert model.plan.clamped == {"Bottom Size Scale": (0.5, 0.7, 1.0)} and model.space["Bottom Size Scale"].default == 0.7
    assert model.plan.fixed["Back Height"] == pytest.approx(0.6) and model.space["Arm Height"].when == (("Has Arms", True),)
    shape = model.generate(model.space.sample(1, seed=0)[0])
    assert shape.n_faces > 0 and "Seat" in shape.label_names
    # An input its condition switches off is sent with the file's value exactly (0.5), not its
    # clamped default (0.7); switched on, with the value given.
    sent = []
    real = model.session.generate
    model.session.generate = lambda values, **kw: (sent.append(dict(values)), real(values, **kw))[1]
    try:
        model.generate({"Legs Type": 0, "Bottom Size Scale": 0.9})
        model.generate({"Legs Type": 1, "Bottom Size Scale": 0.9})
    finally:
        model.session.generate = real
    assert sent[0]["Bottom Size Scale"] == 0.5 and sent[1]["Bottom Size Scale"] == 0.9


def test_params_without_a_spec_list_their_inputs_and_older_stores_vary_every_input(tmp_path):
    """A new config bounding some inputs of a .blend model (no spec) lists them: the others keep the
    file's values. A family stored before lists existed is read with no list: what it varied then."""
    from proctex.store.config import BuildConfig, with_legacy

    blend = tmp_path / "m.blend"
    blend.write_bytes(b"BLENDER")
    source = {"blender": {"file": str(blend), "object": "M"}, "params": {"Width": [1.0, 2.0]}}
    assert BuildConfig.from_dict({"source": source}).source.listed == ["Width"]
    assert BuildConfig.from_dict({"source": {**source, "listed": ["Has Back"]}}).source.listed == ["Has Back"]
    old = BuildConfig.from_dict({"source": source}).to_dict()
    del old["source"]["listed"]  # as a store written before
    assert BuildConfig.from_dict(with_legacy(old)).source.listed is None
    assert BuildConfig.from_dict({"source": {"model": "chair", "params": {"seat_height": [0.4, 0.5]}}}).source.listed is None


@needs_bpy
@pytest.mark.parametrize(
    "file,obj,prompt,expect",
    [
        ("chair.blend", "Cube", "a chair with a blue leather seat, a light oak back and brass legs", {"Seat": "blue", "Back": "light", "Legs": "brass"}),
        ("table.blend", "Cube", "a table with a white marble top and black steel legs", {"Top": "light", "Legs": "dark"}),
        # "boards" names every group whose name holds the word (the side, back and dividing boards): the
        # shelves' geometric test takes no upright board, and without the names no board is white
        (
            "cabinet.blend",
            "Cabinet",
            "a cabinet in red lacquer with white boards and black legs",
            {"Board Right": "light", "Board Back": "light", "Board Left": "light", "Dividing Boards": "light", "Legs": "dark", "Drawers": "red"},
        ),
    ],
)
def test_the_prompt_lands_on_the_parts_the_node_tree_names(file, obj, prompt, expect):
    """The handed-out chair, table and cabinet: their groups carry the node tree's names, and a prompt
    naming parts paints them; the colours are read back per named group from the painted textures."""
    from proctex.geometry.parts import analyse
    from proctex.store.config import BuildConfig
    from proctex.texture.paint_loop import paint_template

    if not (REAL / file).is_file():
        pytest.skip("the shared .blend files are absent")
    cfg = BuildConfig.from_dict({"source": {"blender": {"file": str(REAL / file), "object": obj}, "params_spec": str(REAL / f"sp_{file.split('.')[0]}.json")}})
    model = cfg.procedural_model()
    for params in model.space.sample(3, seed=5):
        shape = model.generate(params)
        grouping = analyse(shape)
        tex = paint_template(shape, grouping, prompt, size=32, up="z")
        by_name: dict[str, list] = {}
        for g in grouping.groups:
            if not g.degenerate and g.label in expect:
                by_name.setdefault(g.label, []).append(tex.groups[g.index].image[tex.groups[g.index].painted].mean(0))
        assert by_name, (params, [g.label for g in grouping.groups])
        for name, colours in by_name.items():
            for r, g, b in colours:
                ok = {"blue": b > r + 0.05, "light": (r + g + b) / 3 > 0.55, "dark": (r + g + b) / 3 < 0.3, "brass": r > b + 0.1 and g > b, "red": r > g + 0.15 and r > b + 0.15}[expect[name]]
                assert ok, (file, name, expect[name], (r, g, b), params)
