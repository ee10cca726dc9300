"""Adaptive tessellation of the built-in models (segment counts follow the parts' sizes).

Fixed mode must stay bit-identical to the meshes the library always produced; adaptive mode must
keep the parts, their grouping and their canonical coordinates exact, while changing almost every
part's connectivity when the parameters change.
"""

import hashlib

import numpy as np
import pytest
import trimesh

from proctex.correspond.metrics import canonical_lookup
from proctex.geometry import primitives as P
from proctex.geometry.parts import part_mesh, segment
from proctex.geometry.surface import sample_surface
from proctex.geometry.surface import interpolate
from proctex.models import get_model, list_models
from proctex.models.furniture import Desk

MODELS = list_models()

# SHA-256 of (vertices, faces, canonical) bytes in fixed mode, recorded before adaptive tessellation
# existed: (at the defaults, another parameter setting, at that setting).
FIXED_HASHES = {
    "cake": (
        "9629cffe7d2decebf2cb69b8e8a64c6354313cd865ec2e3fa3b5f9612e2689e6",
        {"tiers": 3, "radius": 0.09714585609906061, "tier_height": 0.055472601544084586, "shrink": 0.74390389741947,
            "candles": 8, "candle_height": 0.03568927261120207, "plate_margin": 0.017755393681669965},
        "e16481336bfa47fecc18812abd90b36886d7ea112ff8988dc5dd5ed69e892639",
    ),
    "chair": (
        "1f7cf509a81289cd3a3e67951b262993e9c8bc4964d249df03382f1ba9b6d4c6",
        {"seat_width": 0.5013747006971923, "seat_depth": 0.4057187841485909, "seat_height": 0.44475616247053534,
            "seat_thickness": 0.04498665241937083, "back_height": 0.5491604197730934,
            "leg_thickness": 0.032844636305601034, "slats": 2, "arms": True, "arm_height": 0.20877175133514808},
        "55d40d2bf5565003271dc34b077b86e4cee66e603780a8e60ef721a42eceee64",
    ),
    "desk": (
        "ff8f71511518900c1aba6195a8aaef84b2a005fa0c92634b0e277a5562196dee",
        {"width": 1.5406650703850255, "depth": 0.5642969603714774, "height": 0.7309452030881691,
            "top_thickness": 0.043983982903245, "leg_size": 0.059874062965964, "drawers": 0},
        "2ee5d2a5074cce3c72dbfcd3b5d05d1d411d2fdb120ba1c42898255ae2689f88",
    ),
    "fork": (
        "77d6c9a7f68e2fc3d4704cb0cb5c45419176b9c599479784464ef99310ee619a",
        {"length": 0.2005498802788769, "handle_width": 0.011285939207429546, "head_width": 0.021713424370580298,
            "tines": 5, "tine_length": 0.04991604197730934, "handle_rise": 0.002844636305601036},
        "292a55712f699d2e35b13ba78c383ffdaddd1c96a8ba3665df35dfd92fdb6ae4",
    ),
    "mug": (
        "f2dc22cc1d5a5ad8073fd3f4fec523f9bd0ccd2e140e875026ee82acdcee8cd6",
        {"height": 0.11054988027887691, "radius": 0.03428646402476515, "taper": -0.020975350117858643,
            "wall": 0.006997330483874166, "handle_span": 0.7487406296596401, "handle_reach": 0.02041794085976088,
            "handle_thickness": 0.004236176601285997},
        "86ff34cefa3b52356a69c8ad34b3ea52024229de48be230bf5efe0cf352d906c",
    ),
    "mushroom": (
        "61546a4f50d5cf0dab747ea0ab85621184799a787f19705dea39a34b16021871",
        {"cap_radius": 0.05703325351925127, "cap_dome": 0.435729280495303, "stem_height": 0.058567121852901506,
            "stem_radius": 0.012596262677423833, "n_small": 3, "small_scale": 0.3855579538200129},
        "c357bb270a6eb484cd5d098f3ca3e2819309147537ec68215e1dd0577d70dfbb",
    ),
    "pumpkin": (
        "2646216951264c231d28ea0eca745c33868d454dfed5692f54896f8dc9b30f64",
        {"radius": 0.1948913274568179, "squash": 0.546445440557216, "ribs": 7, "rib_depth": 0.141951948709735,
            "stem_length": 0.07979010494327335, "stem_radius": 0.009137854522240415, "stem_bend": 0.1629804270095992,
            "tendril": True},
        "60ba948a6f99c24935dbadfbac2adc9430ea4c61e206f4f3c15aac9b6c7bde1c",
    ),
    # The shell's canonical s counts whorls back from the aperture since issue 16 (vertices and faces
    # unchanged: their digest without canonical is the same as before).
    "shell": (
        "21c53f07f4a60293c0a94e32e6b9f89a1c1ae93271199b9e4df0a3824c8314dc",
        {"length": 0.11434144717794098, "turns": 3.142969603714773, "growth": 1.8403972339698609,
            "spire": 1.3393059258072832, "aperture": 0.7487406296596401, "ribbing": 0.011378545222404144},
        "c4a2a5cebda9f0194d7b2eaf0c1a29f902068446fc03585a162ad770b70272ea",
    ),
    "sofa": (
        "f1c8dd32a77cea715e9e795c988b708efc0151da71c211a1c21e5f7e2c6ff03c",
        {"seats": 3, "seat_width": 0.5428646402476516, "depth": 0.9118904061763383,
            "seat_height": 0.4799466096774833, "back_height": 0.9989505247163667,
            "cushion_thickness": 0.12280086337520467, "arm_height": 0.5618088300642999,
            "arm_width": 0.1435070957805911},
        "f872a003df23bf0258c6681765c3b34b0672eff9849af32f5f11acc0bf1b59b5",
    ),
    "stair": (
        "ad38d503eb68f82132d850ee0dbb25ca47ac2809b05f94288d2926be012e8923",
        {"steps": 9, "width": 0.7714585609906061, "rise": 0.16547260154408458, "run": 0.2999466096774833,
            "tread_thickness": 0.04991604197730934, "handrail": True},
        "b89fddff645d19b32a92f795450d20c6065fd29b15d043bb70dae3b622bdbb73",
    ),
    "table": (
        "36492984e0f56a1a40ab207748d92105894cf60e7aafee09f8e9c046362f9d49",
        {"top_shape": 'rect', "width": 1.0143232012382577, "depth": 0.7237808123526767, "height": 0.7599466096774834,
            "top_thickness": 0.04989505247163667, "legs": 3, "leg_radius": 0.02157451067523998, "apron": True},
        "1cd1b3b59577c3e43a0ea340ee83c8066d20369e6a209369b26695b2e02873fb",
    ),
    "vase": (
        "05bbc67dbf65e0b484963628d41a4367459ceb7442f05b7805f02c8dfd85cd20",
        {"height": 0.4703325351925127, "belly": 0.08143232012382576, "belly_height": 0.3583082108085921,
            "neck": 0.0609759743548675, "lip": 0.09970614692058268, "wall": 0.005137854522240415},
        "c5d94586cac4fdf8eab907a1067add9892a364c51c8c76c75e19390ff8ceaa24",
    ),
}

# Parts whose size depends on no parameter: their adaptive tessellation cannot change.
SIZE_INDEPENDENT = {"desk": {"drawer", "knob"}, "sofa": {"leg"}, "stair": {"post"}}
# Least share of the other parts whose connectivity differs from the defaults' (48 LHS settings);
# the fork's head and tines each follow one parameter with a narrow range (expected share ~0.9).
MIN_CHANGED = {"fork": 0.85}


def digest(shape) -> str:
    h = hashlib.sha256()
    for a in (shape.vertices, shape.faces, shape.canonical):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def parts_by_label(shape) -> dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """label -> [(vertices, faces, canonical) of each non-degenerate part, in build order]."""
    out: dict[str, list] = {}
    for p in segment(shape).parts:
        if not p.degenerate:
            v, f = part_mesh(shape, p)
            out.setdefault(p.label, []).append((v, f, shape.canonical[p.vertices]))
    return out


# ------------------------------------------------------------------------------------------ the API
def test_tessellation_attribute_and_validation():
    assert get_model("vase").tessellation == "fixed"
    m = get_model("chair", tessellation="adaptive")
    assert m.tessellation == "adaptive" and m.describe()["tessellation"] == "adaptive"
    assert "tessellation" not in m.space.names
    assert Desk(tessellation="adaptive").tessellation == "adaptive"
    for bad in ("Adaptive", "", None, 1):
        with pytest.raises(ValueError, match="fixed.*adaptive"):
            get_model("desk", tessellation=bad)
        with pytest.raises(ValueError, match="fixed.*adaptive"):
            Desk(tessellation=bad)


def test_resolution_helpers():
    assert P.segment_count(1.0, 0.3) == 3 and P.segment_count(0.01, 0.3, 2) == 2
    with pytest.raises(ValueError):
        P.segment_count(1.0, 0.0)
    # Bars get rings along their length at half (or 1 / rings_per_width of) their width.
    assert P.box_divisions((0.04, 0.04, 0.8), 0.1) == (1, 1, 40)
    assert P.box_divisions((0.04, 0.04, 0.8), 0.1, rings_per_width=1) == (1, 1, 20)
    assert P.box_divisions((1.2, 0.6, 0.03), 0.1) == (12, 6, 1)
    np.testing.assert_array_equal(P.split_spans([0.0, 0.25, 1.0], [1, 3]), [0.0, 0.25, 0.5, 0.75, 1.0])
    np.testing.assert_allclose(P.uniform_s(8, np.linspace(0, 1, 8)), np.arange(1, 9) / 9)


def test_box_accepts_explicit_canonical_lattices():
    part = P.box((2.0, 1.0, 1.0), divisions=([0.0, 0.1, 1.0], 2, [0.0, 1.0]))
    xs = np.unique(part.canonical[:, 0])
    np.testing.assert_allclose(xs, [0.0, 0.1, 1.0])
    assert len(part.vertices) == 3 * 3 * 2  # one segment along z: every lattice point is on the boundary
    mesh = trimesh.Trimesh(part.vertices, part.faces, process=False)
    assert mesh.is_watertight and mesh.volume == pytest.approx(2.0)
    for bad in (([0.0, 0.5], 1, 1), ([0.2, 1.0], 1, 1), ([0.0, 0.6, 0.4, 1.0], 1, 1), (0, 1, 1), (1, 1)):
        with pytest.raises(ValueError):
            P.box((1.0, 1.0, 1.0), divisions=bad)


def test_rounded_box_bands_keep_their_canonical_extent():
    kw = dict(size=(1.0, 0.5, 0.4), divisions=(5, 6, 5), round_lo=(0.1, 0.0, 0.1), round_hi=(0.1, 0.0, 0.1), edge_segments=2)
    fixed = P.rounded_box(**kw)
    fine = P.rounded_box(**kw, middle=(7, 9, 4))
    for part in (fixed, fine):
        on_band = np.isclose(part.canonical[:, 0], 2 / 5)  # the band's inner edge: flat side starts here
        np.testing.assert_allclose(part.vertices[on_band, 0], -0.5 + 0.1)
    assert len(fine.vertices) > len(fixed.vertices)
    with pytest.raises(ValueError):
        P.rounded_box(**kw, middle=(0, 1, 1))


# ----------------------------------------------------------------------------------- fixed: as ever
@pytest.mark.parametrize("name", MODELS)
def test_fixed_tessellation_is_bit_identical(name):
    default_hash, other, other_hash = FIXED_HASHES[name]
    model = get_model(name)
    assert digest(model.generate()) == default_hash
    assert digest(model.generate(other)) == other_hash


# ---------------------------------------------------------------------------------- adaptive: valid
@pytest.mark.parametrize("name", MODELS)
def test_adaptive_parts_closed_outward_and_counted(name):
    """Parts and groups as ``expected_counts`` says (groups are the label classes, as in
    test_models_furniture; ``analyse`` is not run here, it takes seconds on some shapes), parts
    sharing a label are copies with one connectivity (up to a mirror's winding), closed and outward."""
    model = get_model(name, tessellation="adaptive")
    for params in [model.space.defaults()] + model.space.sample(2, seed=11, method="lhs"):
        shape = model.generate(params)
        assert np.all(np.isfinite(shape.vertices)) and np.all(np.isfinite(shape.canonical))
        parts = segment(shape).parts
        assert (len(parts), len({p.label for p in parts})) == model.expected_counts(params), params
        assert len(shape.label_names) == len({p.label for p in parts})
        for label, copies in parts_by_label(shape).items():
            assert len(copies) == sum(p.label == label for p in parts)  # none degenerate
            f0 = copies[0][1]  # mirrored copies have the reverse winding
            assert all(np.array_equal(f, f0) or np.array_equal(f, f0[:, ::-1]) for _, f, _ in copies), label
        for part in parts:
            v, f = part_mesh(shape, part)
            mesh = trimesh.Trimesh(v, f, process=False)
            assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0, (part.label, params)


@pytest.mark.parametrize("name", MODELS)
def test_adaptive_vertex_budget(name):
    fixed = get_model(name).generate().n_vertices
    adaptive = get_model(name, tessellation="adaptive").generate().n_vertices
    assert 0.5 <= adaptive / fixed <= 2.1, (fixed, adaptive)


def changed_share(name: str, n: int = 48, seed: int = 0) -> tuple[float, dict[str, list[bool]]]:
    """Share of the size-dependent parts whose connectivity differs from the part with the same
    label and rank at the defaults (labels absent at the defaults are skipped), and per label the
    outcomes."""
    model = get_model(name, tessellation="adaptive")
    ref = parts_by_label(model.generate())
    outcome: dict[str, list[bool]] = {}
    for params in model.space.sample(n, seed=seed, method="lhs"):
        for label, parts in parts_by_label(model.generate(params)).items():
            if label not in ref:
                continue
            for i, (v, f, _) in enumerate(parts):
                rv, rf, _ = ref[label][min(i, len(ref[label]) - 1)]
                outcome.setdefault(label, []).append(len(v) != len(rv) or f.shape != rf.shape or not np.array_equal(f, rf))
    counted = [c for label, cs in outcome.items() if label not in SIZE_INDEPENDENT.get(name, ()) for c in cs]
    return float(np.mean(counted)), outcome


@pytest.mark.parametrize("name", MODELS)
def test_adaptive_connectivity_follows_the_parameters(name):
    share, outcome = changed_share(name)
    assert share >= MIN_CHANGED.get(name, 0.9), {k: np.mean(v) for k, v in outcome.items()}
    # Parts of a fixed size keep their tessellation: the shortcut legitimately applies to them.
    for label in SIZE_INDEPENDENT.get(name, ()):
        assert label in outcome and not any(outcome[label])


# ------------------------------------------------------------------------------ adaptive: canonical
def canonical_errors(name: str, params, n: int = 400) -> dict[str, tuple[float, float]]:
    """Per label, the (mean, p99) distance between surface points of the fixed mesh and the points
    with the same canonical coordinates on the adaptive mesh (``canonical_lookup``: closest point on
    the canonical mesh, same face and barycentrics on the real one), relative to the part's
    bounding-box diagonal."""
    fixed = get_model(name).generate(params)
    adaptive = get_model(name, tessellation="adaptive").generate(params)
    fa, aa = parts_by_label(fixed), parts_by_label(adaptive)
    assert {k: len(v) for k, v in fa.items()} == {k: len(v) for k, v in aa.items()}
    out: dict[str, tuple[float, float]] = {}
    for label in fa:
        (fv, ff, fc), (av, af, ac) = fa[label][0], aa[label][0]  # copies are congruent: one is enough
        pts, fi, bary = sample_surface(fv, ff, n, seed=0)
        got, _, _ = canonical_lookup(av, af, ac, interpolate(fc, ff, fi, bary))
        d = np.linalg.norm(got - pts, axis=1) / np.linalg.norm(fv.max(0) - fv.min(0))
        out[label] = (float(d.mean()), float(np.percentile(d, 99)))
    return out


@pytest.mark.parametrize("name", MODELS)
def test_adaptive_canonical_coordinates_are_exact(name):
    model = get_model(name)
    for params in [model.space.defaults()] + model.space.sample(1, seed=3):
        for label, (mean, p99) in canonical_errors(name, params).items():
            assert mean < 0.01 and p99 < 0.03, (label, mean, p99, params)


def test_canonical_check_catches_a_count_tied_parametrisation(monkeypatch):
    """With the profile parameter tied to the ring count (s = (k + 1) / (K + 1) for the adaptive
    K), the same canonical coordinates land elsewhere: the check above must fail."""

    def tied(n_fixed, u):
        return (np.arange(len(u)) + 1.0) / (len(u) + 1.0)

    monkeypatch.setattr(P, "uniform_s", tied)
    params = get_model("table").space.defaults()
    mean, p99 = canonical_errors("table", params)["leg"]
    assert mean > 0.02 and p99 > 0.05


def test_canonical_check_catches_count_tied_rounding_bands(monkeypatch):
    """With a rounded box's bands spanning ``edge_segments / n`` of the adaptive lattice (the knot
    tied to the count, as the fixed tessellation's code reads), the check above must fail."""
    rounded_box = P.rounded_box

    def tied(size, center=(0.0, 0.0, 0.0), divisions=(4, 4, 4), round_lo=(0.0,) * 3, round_hi=(0.0,) * 3,
             edge_segments=2, warp=None, middle=None):
        if middle is not None:
            bands = (np.asarray(round_lo) > 0).astype(int) + (np.asarray(round_hi) > 0).astype(int)
            divisions, middle = np.asarray(middle) + edge_segments * bands, None
        return rounded_box(size, center, divisions, round_lo, round_hi, edge_segments, warp, middle)

    monkeypatch.setattr(P, "rounded_box", tied)
    mean, p99 = canonical_errors("sofa", get_model("sofa").space.defaults())["seat_cushion"]
    assert mean > 0.02 and p99 > 0.05
