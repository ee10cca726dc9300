""".blend files as family sources (issue 19, first slice): a Geometry Nodes model built in code,
saved, and used as a black box through its own Blender process. Skipped with the reason where no
Python with ``bpy`` exists (``make blender`` makes ``.venv-blender``)."""

from __future__ import annotations

import subprocess
import textwrap

import numpy as np
import pytest

from proctex.family.blender import BlenderModel, blender_python, input_specs
from proctex.geometry.parts import segment

PYTHON = blender_python()
needs_bpy = pytest.mark.skipif(PYTHON is None, reason="no Python with bpy (make blender makes .venv-blender; bpy not installable here?)")

#: A vase-like family: a cylinder whose ring count follows its "Resolution" input (topology
#: changes) and whose depth is "Height"; a bool "Capped" drops the caps.
BUILD_VASE = textwrap.dedent("""
    import sys, bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh = bpy.data.meshes.new("m")
    obj = bpy.data.objects.new("Vase", mesh)
    bpy.context.scene.collection.objects.link(obj)
    ng = bpy.data.node_groups.new("VaseNodes", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    h = ng.interface.new_socket("Height", in_out="INPUT", socket_type="NodeSocketFloat")
    h.default_value, h.min_value, h.max_value = 1.0, 0.2, 3.0
    r = ng.interface.new_socket("Resolution", in_out="INPUT", socket_type="NodeSocketInt")
    r.default_value, r.min_value, r.max_value = 8, 3, 64
    c = ng.interface.new_socket("Capped", in_out="INPUT", socket_type="NodeSocketBool")
    c.default_value = True
    gin, gout = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    cyl = ng.nodes.new("GeometryNodeMeshCylinder")
    ng.links.new(gin.outputs["Height"], cyl.inputs["Depth"])
    ng.links.new(gin.outputs["Resolution"], cyl.inputs["Vertices"])
    switch = ng.nodes.new("FunctionNodeCompare")  # unused: inputs of other types must not confuse the reader
    ng.links.new(cyl.outputs["Mesh"], gout.inputs["Geometry"])
    mod = obj.modifiers.new("GeometryNodes", "NODES")
    mod.node_group = ng
    bpy.ops.wm.save_as_mainfile(filepath=sys.argv[1])
""")


@pytest.fixture(scope="module")
def vase_blend(tmp_path_factory):
    if PYTHON is None:
        pytest.skip("no Python with bpy")
    path = tmp_path_factory.mktemp("blend") / "vase.blend"
    script = path.with_suffix(".py")
    script.write_text(BUILD_VASE)
    done = subprocess.run([PYTHON, str(script), str(path)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and path.exists(), done.stderr[-2000:]
    return path


@needs_bpy
def test_the_modifier_inputs_are_the_parameter_space(vase_blend):
    model = BlenderModel(vase_blend, "Vase")
    try:
        specs = {s.name: s for s in model.space.specs}
        assert set(specs) == {"Height", "Resolution", "Capped"}
        assert (specs["Height"].kind, specs["Height"].low, specs["Height"].high, specs["Height"].default) == ("continuous", 0.2, 3.0, 1.0)
        assert (specs["Resolution"].kind, specs["Resolution"].low, specs["Resolution"].high) == ("integer", 3, 64)
        assert specs["Capped"].kind == "choice" and specs["Capped"].options == (False, True)
    finally:
        model.close()


@needs_bpy
def test_generation_is_deterministic_and_the_topology_follows_the_inputs(vase_blend):
    model = BlenderModel(vase_blend, "Vase", bounds={"Resolution": [4, 40]}, pins={"Capped": True})
    try:
        assert [s.name for s in model.space.specs] == ["Height", "Resolution"]
        a = model.generate({"Height": 1.5, "Resolution": 8})
        b = model.generate({"Height": 1.5, "Resolution": 8})
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
        assert np.isclose(np.ptp(a.vertices[:, 2]), 1.5)  # the depth follows "Height"
        c = model.generate({"Height": 1.5, "Resolution": 32})
        assert c.n_vertices == 4 * a.n_vertices and c.n_faces > a.n_faces  # the ring follows "Resolution"
        assert segment(c).n_parts == 1 and model.last_seconds >= 0
        with pytest.raises(ValueError):
            model.generate({"Resolution": 64})  # outside the narrowed bounds
    finally:
        model.close()


@needs_bpy
def test_bad_files_objects_and_modifiers_are_clear_errors(vase_blend, tmp_path):
    with pytest.raises(ValueError, match="no such .blend"):
        BlenderModel(tmp_path / "missing.blend", "Vase")
    with pytest.raises(ValueError, match="no object 'Table'"):
        BlenderModel(vase_blend, "Table")
    with pytest.raises(ValueError, match="no Geometry Nodes modifier 'Other'"):
        BlenderModel(vase_blend, "Vase", modifier="Other")
    with pytest.raises(ValueError, match="must lie within"):
        BlenderModel(vase_blend, "Vase", bounds={"Height": [0.0, 9.0]})


def test_input_specs_need_bounds_for_an_unbounded_input():
    inputs = [{"name": "Size", "identifier": "Socket_1", "type": "float", "default": 1.0, "min": -3.4e38, "max": 3.4e38}]
    with pytest.raises(ValueError, match="give it bounds"):
        input_specs(inputs)
    space, pins = input_specs(inputs, bounds={"Size": [0.5, 2.0]})
    assert space.specs[0].low == 0.5 and pins == {}
    with pytest.raises(ValueError, match="no input 'Nope'"):
        input_specs(inputs, pins={"Nope": 1})


@needs_bpy
@pytest.mark.slow
def test_a_blend_family_builds_and_transfers_new_parameters(vase_blend, tmp_path, capsys):
    """``proctex build --blend`` samples the .blend through its Blender process, paints, solves
    pairs and trains; ``proctex transfer`` textures new parameters (a new ring count) into a GLB."""
    import json

    from proctex.cli import main
    from proctex.family.store import FamilyStore
    from proctex.texture.gltf_read import read_textured_glb

    out = tmp_path / "fam"
    code = main(["build", "--blend", str(vase_blend), "--object", "Vase", "--prompt", "blue ceramic", "--n-train", "3", "--n-test", "0",
                 "--texture-size", "64", "--points", "200", "--iterations", "20", "--train-iterations", "20", "--out", str(out), "--quiet",
                 "--stages", "sample,template,paint,pairs,train"])
    assert code == 0, capsys.readouterr().err
    state = FamilyStore(out).read_json("family.json")
    assert state["config"]["source"]["blender"]["object"] == "Vase"
    assert all(state["stages"][s]["state"] == "done" for s in ("sample", "template", "paint", "pairs", "train"))
    glb = tmp_path / "v.glb"
    code = main(["transfer", str(out), "--params", json.dumps({"Height": 2.0, "Resolution": 24}), "--out", str(glb)])
    assert code == 0, capsys.readouterr().err
    mesh = read_textured_glb(glb.read_bytes())
    assert len(mesh.faces) > 0 and len(mesh.textures) >= 1


@needs_bpy
@pytest.mark.slow
@pytest.mark.ray
def test_a_blend_family_fans_out_on_ray_like_any_other_source(vase_blend, tmp_path):
    """Sampling and cage pairs of a .blend family as Ray tasks: each worker opens the file once in
    its own Blender process; the samples equal the single-process build's."""
    import ray

    from proctex.family.config import BuildConfig
    from proctex.family.pipeline import build
    from proctex.family.stages import samples
    from proctex.family.store import FamilyStore
    from workflows.build import build_on_ray

    cfg = BuildConfig.from_dict({"source": {"blender": {"file": str(vase_blend), "object": "Vase"}, "n_train": 4, "n_test": 0},
                                 "paint": {"prompt": "blue ceramic", "texture_size": 32}, "corr_points": 200, "cage": {"iterations": 10}})
    stages = ("sample", "template", "paint", "pairs")
    local = FamilyStore(tmp_path / "local")
    build(local, cfg, stages=stages, log=lambda *_: None)
    was_up = ray.is_initialized()
    try:
        state = build_on_ray(str(tmp_path / "ray"), cfg, stages=stages, num_cpus=2, log=lambda *_: None, quiet=True)
    finally:
        if not was_up:
            ray.shutdown()
    assert all(state["stages"][s]["state"] == "done" for s in stages)
    on_ray = FamilyStore(tmp_path / "ray")
    assert [(r["id"], r["faces"], r["params"]) for r in samples(on_ray)] == [(r["id"], r["faces"], r["params"]) for r in samples(local)]
    assert len({r["faces"] for r in samples(on_ray)}) > 1  # the ring count varies across the family
