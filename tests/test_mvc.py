"""Mean value coordinates: fast PyTorch version against the loop reference, and their defining facts."""

import numpy as np
import pytest
import torch

from proctex._reference.mvc import mean_value_coordinates_reference
from proctex.correspond.mvc import mean_value_coordinates
from proctex.geometry.primitives import box


def _octahedron() -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    f = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    return v, f


def _warped_box() -> tuple[np.ndarray, np.ndarray]:
    """A subdivided box with jittered vertices: an irregular, non-convex closed cage."""
    b = box((2.0, 1.4, 1.0), (0.2, -0.1, 0.3), (2, 3, 2))
    rng = np.random.default_rng(5)
    return b.vertices + rng.normal(scale=0.06, size=b.vertices.shape), b.faces


CAGES = {"octahedron": _octahedron(), "box": (box((2, 1.5, 1), (0, 0, 0), (2, 2, 2)).vertices, box((2, 1.5, 1), (0, 0, 0), (2, 2, 2)).faces), "warped": _warped_box()}


@pytest.mark.parametrize("name", sorted(CAGES))
def test_fast_matches_reference_inside_and_outside(name):
    cv, cf = CAGES[name]
    rng = np.random.default_rng(1)
    lo, hi = cv.min(0), cv.max(0)
    pts = rng.uniform(lo - 0.5, hi + 0.5, size=(60, 3))  # inside and outside the cage
    fast = mean_value_coordinates(pts, cv, cf).numpy()
    ref = mean_value_coordinates_reference(pts, cv, cf)
    np.testing.assert_allclose(fast, ref, atol=1e-9)
    np.testing.assert_allclose(fast.sum(1), 1.0, atol=1e-12)
    # Linear precision: the weights reproduce the point itself (and hence every linear function).
    np.testing.assert_allclose(fast @ cv, pts, atol=1e-9)
    A, b = rng.normal(size=(3, 2)), rng.normal(size=2)
    np.testing.assert_allclose(fast @ (cv @ A + b), pts @ A + b, atol=1e-9)


def test_weights_are_positive_inside_a_convex_cage():
    cv, cf = CAGES["box"]
    pts = np.random.default_rng(2).uniform(-0.9, 0.9, size=(200, 3)) * [1, 0.75, 0.5]
    w = mean_value_coordinates(pts, cv, cf).numpy()
    assert w.min() > 0


def test_guards_vertex_face_edge_and_coplanar():
    cv, cf = CAGES["warped"]
    tri = cv[cf[7]]
    pts = np.stack(
        [
            cv[3],  # exactly at a cage vertex
            cv[11] + 1e-12,  # within eps of one
            np.array([0.2, 0.3, 0.5]) @ tri,  # on a cage face
            np.array([0.5, 0.5, 0.0]) @ tri,  # on a cage edge
        ]
    )
    w = mean_value_coordinates(pts, cv, cf).numpy()
    ref = mean_value_coordinates_reference(pts, cv, cf)
    np.testing.assert_allclose(w, ref, atol=1e-9)
    assert w[0, 3] == 1.0 and np.count_nonzero(w[0]) == 1
    assert w[1, 11] == 1.0
    # On a face: exactly the triangle's barycentric coordinates, nothing elsewhere.
    np.testing.assert_allclose(w[2, cf[7]], [0.2, 0.3, 0.5], atol=1e-9)
    assert np.count_nonzero(np.abs(w[2]) > 1e-12) == 3
    np.testing.assert_allclose(w @ cv, pts, atol=1e-9)
    assert np.all(np.isfinite(w))


def test_coplanar_with_a_face_outside_it():
    cv, cf = CAGES["box"]  # top face at z = 0.5 spans |x| <= 1, |y| <= 0.75
    pts = np.array([[1.7, 0.2, 0.5], [-0.3, 1.5, 0.5], [2.0, 2.0, -0.5]])
    w = mean_value_coordinates(pts, cv, cf).numpy()
    # The coplanar face's contribution vanishes in the limit; the guard decides at ~eps in its angle,
    # which leaves an error of order sqrt(eps) ~ 1.5e-8 in the weights (measured: 6e-14 on AVX2 and
    # AVX-512 kernels, 2.5e-8 on ATen's default ones: a quarter of the old 1e-7). 1e-6 keeps 40x
    # above that and fails on any wrong handling of the face (weights of order 0.1 off by 1e-2).
    np.testing.assert_allclose(w, mean_value_coordinates_reference(pts, cv, cf), atol=1e-6)
    np.testing.assert_allclose(w @ cv, pts, atol=1e-9)


def test_chunks_dtype_and_tensor_inputs_agree():
    cv, cf = CAGES["warped"]
    pts = np.random.default_rng(3).uniform(-1, 1, size=(37, 3))
    a = mean_value_coordinates(pts, cv, cf, chunk=1024)
    b = mean_value_coordinates(torch.tensor(pts), torch.tensor(cv), torch.tensor(cf), chunk=5)
    torch.testing.assert_close(a, b)
    c = mean_value_coordinates(pts, torch.tensor(cv, dtype=torch.float32), cf)
    assert c.dtype == torch.float32
    np.testing.assert_allclose(c.numpy(), a.numpy(), atol=2e-3)


@pytest.mark.slow  # over 15 s: not in make test's second pass (tests/suite.py)
def test_differentiable_wrt_cage_vertices():
    cv, cf = CAGES["warped"]
    pts = torch.tensor(np.random.default_rng(4).uniform(-0.5, 0.5, size=(4, 3)))
    cage = torch.tensor(cv, requires_grad=True)
    assert torch.autograd.gradcheck(lambda c: mean_value_coordinates(pts, c, cf), (cage,), eps=1e-6, atol=1e-5)
    # A point deformed by the cage follows a translation of the cage exactly.
    w = mean_value_coordinates(pts, cage, cf)
    moved = w @ (cage + torch.tensor([0.3, -0.2, 0.1], dtype=torch.float64))
    torch.testing.assert_close(moved, pts + torch.tensor([0.3, -0.2, 0.1], dtype=torch.float64))
    (w**2).sum().backward()
    assert torch.isfinite(cage.grad).all()


def test_bad_input():
    cv, cf = CAGES["box"]
    with pytest.raises(ValueError, match="NaN"):
        mean_value_coordinates(np.array([[np.nan, 0, 0]]), cv, cf)
    with pytest.raises(ValueError, match="points must be"):
        mean_value_coordinates(np.zeros((3, 2)), cv, cf)
    with pytest.raises(ValueError, match="cage faces"):
        mean_value_coordinates(np.zeros((1, 3)), cv, cf[:2])
    with pytest.raises(ValueError, match="out of range"):
        mean_value_coordinates(np.zeros((1, 3)), cv, cf + 100)
    assert mean_value_coordinates(np.zeros((0, 3)), cv, cf).shape == (0, len(cv))
