"""The sweep chart of tube-like parts (proctex.geometry.chart): along and around a part."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from proctex.geometry.chart import cotangent_laplacian, sweep_chart
from proctex.geometry.primitives import box
from proctex.geometry.sweeps import tube


def _coil(turns: float, radius: float = 0.12, pitch: float = 0.6):
    """A tube swept along a helix of ``turns`` turns about z; returns the part, the helix and its
    parameter (0..1 along the helix, proportional to arc length)."""
    k = int(60 * turns)
    u = np.linspace(0.0, 1.0, k)
    a = 2 * np.pi * turns * u
    path = np.stack([np.cos(a), np.sin(a), pitch * turns * u], axis=1)
    return tube(path, radius, n_sides=12), path, u


@pytest.mark.parametrize("turns", [2.0, 3.5, 5.0])
def test_the_chart_orders_a_helix_and_counts_its_turns(turns):
    """Every vertex's position along the chart is its place along the helix (to 0.01 of the
    length, either direction), the centre line winds the known number of turns about z, and the
    part reads as a tube (length many times its radius)."""
    part, path, u = _coil(turns)
    chart = sweep_chart(part.vertices, part.faces)
    _, j = cKDTree(path).query(part.vertices)
    truth = u[j]
    if np.corrcoef(chart.s, truth)[0, 1] < 0:
        truth = 1.0 - truth  # the Fiedler vector's sign is arbitrary
    assert np.abs(chart.s - truth).max() < 0.01
    assert abs(chart.turns - turns) < 0.05
    np.testing.assert_array_equal(chart.reference, [0.0, 0.0, 1.0])
    assert chart.aspect > 50 and abs(chart.radius - 0.12) < 0.02 and chart.tubular
    assert np.all((chart.theta >= -np.pi) & (chart.theta <= np.pi))


def test_the_chart_angle_goes_once_around_each_ring():
    """Around a straight tube the angle of the ring's vertices covers the circle once, in order."""
    path = np.stack([np.linspace(0.0, 4.0, 40), np.zeros(40), np.zeros(40)], axis=1)
    part = tube(path, 0.3, n_sides=16)
    chart = sweep_chart(part.vertices, part.faces)
    mid = np.flatnonzero(np.abs(part.vertices[:, 0] - path[20, 0]) < 1e-9)
    assert len(mid) == 16
    th = np.unwrap(chart.theta[mid])
    # Exact in exact arithmetic (each ring's vertices share a level set, so the centre line lies on
    # the axis): what is left is rounding, ~1e-16 relative on angles of order 1 and centre-line
    # offsets of order 1e-17 at distances >= 0.2 from the axis. 1e-9 holds on any kernels and
    # fails when a ring is split between level sets (a centre line off the axis by ~1e-2 moved the
    # angle by 0.015-0.046 and turns to 0.03-0.05, depending on OpenBLAS's kernel).
    assert abs(abs(th[-1] - th[0]) - 2 * np.pi * 15 / 16) < 1e-9
    assert chart.turns < 1e-9
    assert np.allclose(np.diff(th), 2 * np.pi / 16, rtol=0, atol=1e-9)  # evenly spaced, in order


def test_a_uv_seam_split_does_not_cut_the_chart():
    """The same coil with every vertex of one seam duplicated (as UV exports do) gives the same chart."""
    part, _, _ = _coil(3.0)
    v, f = part.vertices, part.faces.copy()
    seam = np.flatnonzero(np.abs(np.arctan2(v[:, 1], v[:, 0])) < 0.05)
    dup = np.arange(len(v), len(v) + len(seam))
    v2 = np.concatenate([v, v[seam]])
    remap = np.arange(len(v))
    remap[seam] = dup
    faces_right = v[f].mean(axis=1)[:, 1] > 0  # faces on one side of the seam use the copies
    f[faces_right] = remap[f[faces_right]]
    whole = sweep_chart(v, part.faces)
    split = sweep_chart(v2, f)
    s = split.s[: len(v)].copy()
    moved = np.isnan(s[seam])  # seam vertices only the copies use now
    assert moved.any()
    s[seam[moved]] = split.s[dup[moved]]
    assert not np.isnan(s).any()
    if np.corrcoef(s, whole.s)[0, 1] < 0:
        s = 1.0 - s
    assert np.abs(s - whole.s).max() < 1e-6


def test_only_tubes_are_tubular_and_the_chart_is_deterministic():
    """A coil and a tube of elliptic section are tubes; a long flat slab (a sofa's back panel) is
    not; a mug's thin-walled body is a short folded tube that winds no turn; the chart of the
    same mesh is the same every time."""
    from proctex.geometry.parts import analyse, part_mesh
    from proctex.models import get_model

    coil, _, _ = _coil(3.0)
    assert sweep_chart(coil.vertices, coil.faces).tubular
    path = np.stack([np.linspace(0.0, 4.0, 40), np.zeros(40), np.zeros(40)], axis=1)
    oval = tube(path, 0.3, n_sides=16, scale_xy=(1.0, 0.5))
    assert sweep_chart(oval.vertices, oval.faces).tubular
    slab = box((2.0, 0.06, 0.78), divisions=(20, 2, 8))
    chart = sweep_chart(slab.vertices, slab.faces)
    assert not chart.tubular and chart.spread > 0.4
    mug = get_model("mug").generate()
    g = analyse(mug)
    v, f = part_mesh(mug, g.parts[g.groups[0].representative])
    first, second = sweep_chart(v, f), sweep_chart(v, f)
    # The mug's body is a folded tube (outer wall, rim, inner wall): its level sets are rings, its
    # centre line runs up the axis and back and winds no turn (a surface of revolution), and it is
    # far too short to be swept (with rings split between level sets by the eigensolver's last
    # bits, its centre line zigzagged: aspect 128, 4.2 turns).
    from proctex.correspond.cage import CageConfig

    assert first.spread < 0.1 and first.turns < 1e-9
    assert first.aspect < CageConfig().sweep_aspect / 2
    np.testing.assert_array_equal(first.s, second.s)


def test_a_box_is_not_a_tube_and_bad_parts_are_refused():
    b = box((1.0, 0.8, 0.6), divisions=(4, 4, 4))
    assert sweep_chart(b.vertices, b.faces).aspect < 10  # round enough, but not long: not tube-like
    L, area = cotangent_laplacian(b.vertices, b.faces)
    np.testing.assert_allclose(L @ np.ones(len(b.vertices)), 0.0, atol=1e-9)  # constants are in its kernel
    assert abs(area.sum() - 2 * (0.8 + 0.48 + 0.6)) < 1e-9
    two = box((1.0, 1.0, 1.0), center=(3.0, 0.0, 0.0))
    v = np.concatenate([b.vertices, two.vertices])
    f = np.concatenate([b.faces, two.faces + len(b.vertices)])
    with pytest.raises(ValueError, match="pieces"):
        sweep_chart(v, f)
    bad = b.vertices.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        sweep_chart(bad, b.faces)
    with pytest.raises(ValueError, match="at least 4"):
        sweep_chart(np.eye(3), np.array([[0, 1, 2]]))


def _fixed_coil(turns: float):
    """A coil whose rings measure their angle from z projected normal to the path (the chart's own
    convention), with its helix and helix parameter."""
    k = int(60 * turns)
    u = np.linspace(0.0, 1.0, k)
    a = 2 * np.pi * turns * u
    path = np.stack([np.cos(a), np.sin(a), 0.6 * turns * u], axis=1)
    return tube(path, 0.12, n_sides=12, normals=np.tile([0.0, 0.0, 1.0], (k, 1))), path, u


def _along_and_around(path, u, points):
    """Helix parameter of the nearest path point, and the angle around the path from z."""
    _, j = cKDTree(path).query(points)
    t = np.gradient(path, axis=0)[j]
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    n = np.array([0.0, 0.0, 1.0]) - t[:, 2:3] * t
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d = points - path[j]
    return u[j], np.arctan2(np.einsum("kd,kd->k", d, np.cross(t, n)), np.einsum("kd,kd->k", d, n))


@pytest.mark.slow  # over 15 s: not in make test's second pass (tests/suite.py)
def test_a_coil_with_more_turns_maps_along_and_around_through_the_charts():
    """Source coil: 3 turns; template: 4. The cage can only follow the volume (a point a third of
    the way along lands far from a third of the way along); the sweep teacher maps every sample to
    the same place along (to 0.005 of the length on average) and around the coil, and deform()
    agrees with it for arbitrary source points."""
    from proctex.correspond.cage import CageConfig
    from proctex.correspond.dense import correspond_parts, deform

    (src, sp, su), (tpl, tp, tu) = _fixed_coil(3.0), _fixed_coil(4.0)
    swept = correspond_parts(src.vertices, src.faces, tpl.vertices, tpl.faces, method="cage", n_points=800, seed=0, cage=CageConfig(sweep=True, iterations=30))
    assert swept.details["teacher"] == "sweep"
    assert abs(swept.details["turns"] - 3.0) < 0.05 and abs(swept.details["template_turns"] - 4.0) < 0.05
    u_s, a_s = _along_and_around(sp, su, swept.source_points)
    u_t, a_t = _along_and_around(tp, tu, swept.points)
    assert np.abs(u_s - u_t).mean() < 0.005 and np.abs(u_s - u_t).max() < 0.02
    assert np.abs(np.angle(np.exp(1j * (a_s - a_t)))).mean() < 0.1
    caged = correspond_parts(src.vertices, src.faces, tpl.vertices, tpl.faces, method="cage", n_points=800, seed=0, cage=CageConfig(sweep=False, iterations=30))
    assert "teacher" not in caged.details
    u_c, _ = _along_and_around(tp, tu, caged.points)
    assert np.abs(u_s - u_c).mean() > 0.03
    # deform() maps arbitrary source points the same way (world in, template normalised frame out)
    centre = (tpl.vertices.min(0) + tpl.vertices.max(0)) / 2
    radius = float(np.abs(tpl.vertices - centre).max())
    moved = deform(swept, src.vertices, np.zeros(3), 1.0) * radius + centre
    u_v, _ = _along_and_around(sp, su, src.vertices)
    u_m, _ = _along_and_around(tp, tu, moved)
    assert np.abs(u_v - u_m).mean() < 0.005


def test_the_sweep_teacher_leaves_parts_that_are_not_tubes_to_the_cage():
    from proctex.correspond.cage import CageConfig
    from proctex.correspond.dense import correspond_parts

    a = box((1.0, 0.8, 0.6), divisions=(4, 4, 4))
    b = box((1.2, 0.7, 0.6), divisions=(3, 5, 4))
    res = correspond_parts(a.vertices, a.faces, b.vertices, b.faces, method="cage", n_points=300, seed=0, cage=CageConfig(sweep=True, iterations=20))
    assert "teacher" not in res.details and "cage" in res.details
    with pytest.raises(ValueError, match="sweep"):
        CageConfig(sweep_aspect=-1.0).validate()
