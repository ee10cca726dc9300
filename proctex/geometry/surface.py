"""Surface geometry: triangle areas and normals, area-weighted sampling, exact closest points.

:class:`SurfaceIndex` answers nearest-surface-point queries exactly. Plain nearest-point queries go
to libigl's AABB tree (compiled; about 100x the speed of the proxy search on a 7k-face sofa part);
the proxy search is the fallback where libigl is missing (``backend="proxies"``) and the engine of
the normal-filtered queries (:meth:`SurfaceIndex.query_oriented`, :meth:`SurfaceIndex.query_facing`):
a KD-tree over face centroids proposes candidates, exact point–triangle distances decide, and a
bound on the triangle size proves no other face can be closer.
:func:`closest_point_bruteforce` is the slow, obviously correct reference of both.
"""

from __future__ import annotations

import atexit
import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from proctex.geometry.rowmath import bounds, cross3, dot3


def normalised_frame(points: np.ndarray) -> tuple[np.ndarray, float]:
    """``(centre (3,), L∞ radius)`` of ``points (n, 3)``: the normalised part frame (docs/correspondence.md)."""
    lo, hi = bounds(points)
    center = (lo + hi) / 2
    return center, float(np.abs(points - center).max())


#: The grid a part's points are snapped to in their normalised frame (:func:`normalised_points`):
#: 2^-32 of the part's half size, far below any texel or tolerance.
FRAME_GRID = 2.0**-32


def snap_to_frame_grid(points: np.ndarray) -> np.ndarray:
    """``points`` (any shape, normalised-frame coordinates of order 1) rounded to :data:`FRAME_GRID`."""
    return np.round(np.asarray(points, dtype=np.float64) / FRAME_GRID) * FRAME_GRID


def normalised_points(points: np.ndarray) -> np.ndarray:
    """``points (n, 3)`` in their own normalised frame (:func:`normalised_frame`: bounding-box centre
    at 0, L∞ radius 1; a point set of no extent is only centred), snapped to :data:`FRAME_GRID`. The
    same part in other units (x 1e3, x 1e-6) reaches this frame with float64 rounding noise (about
    1e-16), which fits of ill-determined rotations (a symmetric cushion's Umeyama fit) amplified to
    1e-8 and exact ties (a box map's edges halfway between two charts) turned into other UVs;
    snapped, every fit and lookup downstream sees the same numbers (the noise crosses a grid
    midpoint about once in 10^6 coordinates)."""
    v = np.asarray(points, dtype=np.float64)
    c, r = normalised_frame(v)
    return snap_to_frame_grid((v - c) / (r if r > 0 else 1.0))


def triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) float64 areas of the triangles ``faces (m, 3)`` over ``vertices (n, 3)``: compiled
    (:mod:`proctex.geometry.mesh_kernels`), the same bits as :func:`triangle_areas_arrays`, which
    answers where numba does not import."""
    try:
        from .mesh_kernels import triangle_areas as compiled
    except ImportError:
        return triangle_areas_arrays(vertices, faces)
    return compiled(vertices, faces)


def triangle_areas_arrays(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """:func:`triangle_areas` in array operations (the compiled form's reference)."""
    tri = vertices[faces]
    n = cross3(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return 0.5 * np.sqrt(dot3(n, n))


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m, 3) float64 unit normals (zero vectors for zero-area faces)."""
    tri = vertices[faces]
    n = cross3(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.sqrt(dot3(n, n))[:, None]
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n, 3) float64 unit area-weighted vertex normals (zero for unreferenced vertices)."""
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = 2 * area
    out = np.zeros((len(vertices), 3))
    for k in range(3):
        np.add.at(out, faces[:, k], n)
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, norm, out=np.zeros_like(out), where=norm > 0)


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, seed: int | np.random.Generator = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Area-weighted uniform samples on a triangle mesh.

    Returns:
        ``(points (n, 3) float64, face index (n,) int64, barycentric (n, 3) float64)``. When the
        surface has zero area, faces are drawn uniformly instead.
    """
    if len(faces) == 0:
        raise ValueError("cannot sample a surface with no faces")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    area = triangle_areas(vertices, faces)
    total = area.sum()
    p = area / total if total > 0 else None
    fi = rng.choice(len(faces), size=n, p=p)
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    bary = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
    tri = vertices[faces[fi]]
    pts = np.einsum("ij,ijk->ik", bary, tri)
    return pts, fi.astype(np.int64), bary


def plane_barycentric(points: np.ndarray, tri: np.ndarray, floor: float = 0.0) -> np.ndarray:
    """(k, 3) barycentrics of ``points`` (k, d) in triangles ``tri`` (k, 3, d), d = 2 or 3 (least
    squares in the triangle's plane: a 3D point is projected on it), each at least ``floor`` (0:
    clamped into the triangle; -1: up to a triangle's size past an edge) and renormalised to sum 1;
    a degenerate triangle gives its centre."""
    e1, e2, d = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], points - tri[:, 0]
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    p1, p2 = (d * e1).sum(1), (d * e2).sum(1)
    den = d11 * d22 - d12 * d12
    ok = np.abs(den) > 1e-30
    den = np.where(ok, den, 1.0)
    l1 = np.where(ok, (d22 * p1 - d12 * p2) / den, 1 / 3)
    l2 = np.where(ok, (d11 * p2 - d12 * p1) / den, 1 / 3)
    lam = np.clip(np.stack([1 - l1 - l2, l1, l2], axis=1), floor, None)
    return lam / lam.sum(axis=1, keepdims=True)


def closest_point_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact closest points on triangles (Ericson, Real-Time Collision Detection §5.1.5), vectorised.

    Args:
        p, a, b, c: (k, 3) float64 query points and triangle corners (row-wise pairs).

    Returns:
        ``(closest (k, 3), barycentric (k, 3))``; degenerate triangles are handled (their closest
        point lies on an edge or corner): an edge of zero length is no region of its own, and a
        triangle that matches no region takes its nearest corner (the compiled form,
        :func:`proctex.geometry.bvh.point_triangle_d2`, takes the same regions).
    """
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    k = len(p)
    ones, zeros = np.ones(k), np.zeros(k)
    with np.errstate(divide="ignore", invalid="ignore"):
        v_ab = np.where(d1 - d3 != 0, d1 / (d1 - d3), 0.0)
        w_ac = np.where(d2 - d6 != 0, d2 / (d2 - d6), 0.0)
        denom_bc = (d4 - d3) + (d5 - d6)
        w_bc = np.where(denom_bc != 0, (d4 - d3) / denom_bc, 0.0)
        denom = va + vb + vc
        ok = denom != 0
        vv = np.where(ok, vb / np.where(ok, denom, 1), 0.0)
        ww = np.where(ok, vc / np.where(ok, denom, 1), 0.0)
    # Regions in priority order: corners, edges, the face, and (all corners equal) corner a.
    conditions = [
        (d1 <= 0) & (d2 <= 0),
        (d3 >= 0) & (d4 <= d3),
        (d6 >= 0) & (d5 <= d6),
        (vc <= 0) & (d1 >= 0) & (d3 <= 0) & (d1 - d3 != 0),
        (vb <= 0) & (d2 >= 0) & (d6 <= 0) & (d2 - d6 != 0),
        (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0) & (denom_bc != 0),
        ok,
    ]
    da, db, dc = (np.einsum("ij,ij->i", x, x) for x in (ap, bp, cp))
    corner_a, corner_b = (da <= db) & (da <= dc), db <= dc  # no region (all corners on one point or line): the nearest corner
    choices = [
        (ones, zeros, zeros),
        (zeros, ones, zeros),
        (zeros, zeros, ones),
        (1 - v_ab, v_ab, zeros),
        (1 - w_ac, zeros, w_ac),
        (zeros, 1 - w_bc, w_bc),
        (1 - vv - ww, vv, ww),
    ]
    nearest = (corner_a.astype(float), (~corner_a & corner_b).astype(float), (~corner_a & ~corner_b).astype(float))
    bary = np.stack([np.select(conditions, [c[j] for c in choices], default=nearest[j]) for j in range(3)], axis=1)
    closest = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c
    return closest, bary


@dataclass
class ClosestPoints:
    """Nearest surface points. ``points (k, 3)``, ``faces (k,) int64``, ``bary (k, 3)``, ``distance (k,)``."""

    points: np.ndarray
    faces: np.ndarray
    bary: np.ndarray
    distance: np.ndarray


def closest_point_bruteforce(vertices: np.ndarray, faces: np.ndarray, query: np.ndarray) -> ClosestPoints:
    """Reference: test every query against every triangle (O(k m) memory in chunks)."""
    query = np.asarray(query, dtype=float)
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    m = len(faces)
    out_p, out_f, out_b, out_d = [], [], [], []
    for q in query:
        cp, bary = closest_point_on_triangles(np.repeat(q[None], m, 0), a, b, c)
        d = np.linalg.norm(cp - q, axis=1)
        i = int(np.argmin(d))
        out_p.append(cp[i]), out_f.append(i), out_b.append(bary[i]), out_d.append(d[i])
    return ClosestPoints(np.array(out_p).reshape(-1, 3), np.array(out_f, np.int64), np.array(out_b).reshape(-1, 3), np.array(out_d))


def _subtriangle_centroids(n: int) -> np.ndarray:
    """(n*n, 3) barycentric centroids of the sub-triangles of a triangle split n times per edge."""
    out = []
    for i in range(n):
        for j in range(n - i):
            # Upward sub-triangle (i, j), (i+1, j), (i, j+1) and, when it exists, the downward one.
            out.append(((3 * i + 1) / (3 * n), (3 * j + 1) / (3 * n)))
            if i + j < n - 1:
                out.append(((3 * i + 2) / (3 * n), (3 * j + 2) / (3 * n)))
    uv = np.array(out)
    return np.stack([1 - uv.sum(1), uv[:, 0], uv[:, 1]], axis=1)


def _points_and_normals(points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(points (q, 3), normals (q, 3))`` as float64, or ``ValueError`` (shapes, NaN or inf)."""
    pts = np.asarray(points, dtype=np.float64)
    nrm = np.asarray(normals, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or nrm.shape != pts.shape:
        raise ValueError(f"points and normals must both be (q, 3), got {pts.shape} and {nrm.shape}")
    if not (np.all(np.isfinite(pts)) and np.all(np.isfinite(nrm))):
        raise ValueError("query points or normals contain NaN or inf")
    return pts, nrm


_IGL: list = []


def _igl():
    """The ``igl`` module (libigl's Python bindings), or None where it does not import."""
    if not _IGL:
        try:
            import igl
        except ImportError:
            igl = None
        _IGL.append(igl)
    return _IGL[0]


_BVH: list = []


def _bvh():
    """The :mod:`proctex.geometry.bvh` module, or None where numba does not import."""
    if not _BVH:
        try:
            from proctex.geometry import bvh
        except ImportError:
            bvh = None
        _BVH.append(bvh)
    return _BVH[0]


#: The indexes holding a libigl AABB tree: their trees are let go at exit, before the interpreter
#: tears the bindings down (nanobind reports instances still alive then as leaks, on stderr).
_TREES: weakref.WeakSet = weakref.WeakSet()


@atexit.register
def _drop_trees() -> None:
    for index in list(_TREES):
        index._aabb = None


class SurfaceIndex:
    """Exact nearest-point queries on a triangle mesh.

    Every triangle is represented by proxy points (its centroid, or the centroids of a regular
    subdivision for large triangles) in a KD-tree. A query checks the faces of its ``k`` nearest
    proxies exactly; the result is proven nearest when the k-th proxy is farther than the best
    distance plus the largest proxy radius, otherwise ``k`` grows for those points.

    Plain :meth:`query` calls go to a tree of boxes instead (built on the first query), exact
    whatever ``exact`` says (exactness costs it nothing): the compiled one of
    :mod:`proctex.geometry.bvh`, or libigl's AABB tree where numba does not import.

    Args:
        vertices: (n, 3) float64; faces: (m, 3) int64 (m >= 1).
        k: proxies checked per query in the first round.
        backend: "auto" (the tree for :meth:`query` where numba or libigl imports, else the proxy
            search), "aabb" (the tree, or ImportError) or "proxies" (the pure search everywhere).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, k: int = 8, backend: str = "auto") -> None:
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        if self.faces.ndim != 2 or self.faces.shape[1] != 3 or len(self.faces) == 0:
            raise ValueError(f"SurfaceIndex needs (m >= 1, 3) faces, got {self.faces.shape}")
        if backend not in ("auto", "aabb", "proxies"):
            raise ValueError(f"backend must be auto, aabb or proxies, got {backend!r}")
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3 or self.faces.min() < 0 or self.faces.max() >= len(self.vertices):
            raise ValueError(f"SurfaceIndex needs (n, 3) vertices that the faces index, got {self.vertices.shape} for indices up to {self.faces.max()}")
        self._aabb: object | None = None
        self._bvh: Any = None  # the compiled tree (:meth:`_aabb_faces`), built on first use
        tree = _bvh() is not None or _igl() is not None
        self._backend = backend if backend != "auto" else ("aabb" if tree else "proxies")
        if self._backend == "aabb" and not tree:
            raise ImportError("SurfaceIndex(backend='aabb') needs numba or libigl (pip install numba)")
        tri = self.vertices[self.faces]
        self._a, self._b, self._c = tri[:, 0], tri[:, 1], tri[:, 2]
        self._k = int(k)
        self._proxy: tuple | None = None  # (tree, owner, max radius), built on first use
        self.normals = face_normals(self.vertices, self.faces)

    def __getstate__(self) -> dict:
        """Pickled without the AABB tree (libigl's objects do not pickle; it is rebuilt on the
        first query)."""
        return {**self.__dict__, "_aabb": None, "_bvh": None}

    def _proxies(self) -> tuple:
        """The proxy search's structure ``(KD-tree of proxies, owning face (p,), max proxy radius)``,
        built on first use (an index that only answers plain queries by the AABB never needs it)."""
        if self._proxy is None:
            tri = self.vertices[self.faces]
            centroids = tri.mean(axis=1)
            radius = np.linalg.norm(tri - centroids[:, None], axis=2).max(axis=1)
            target = max(float(np.median(radius)), 1e-12)
            levels = np.clip(np.ceil(radius / target).astype(np.int64), 1, 64)
            proxies, owner, proxy_r = [], [], [0.0]
            for n in np.unique(levels):
                fi = np.flatnonzero(levels == n)
                w = _subtriangle_centroids(int(n))
                pts = np.einsum("sk,fkd->fsd", w, tri[fi])
                proxies.append(pts.reshape(-1, 3))
                owner.append(np.repeat(fi, len(w)))
                proxy_r.append(float(radius[fi].max()) / n)
            self._proxy = (cKDTree(np.concatenate(proxies)), np.concatenate(owner), max(proxy_r))
        return self._proxy

    @property
    def tree(self) -> cKDTree:
        return self._proxies()[0]

    @property
    def proxy_owner(self) -> np.ndarray:
        return self._proxies()[1]

    @property
    def max_radius(self) -> float:
        return self._proxies()[2]

    @property
    def n_proxies(self) -> int:
        return len(self.proxy_owner)

    @property
    def k(self) -> int:
        return min(self._k, self.n_proxies)

    def _candidates(self, pts: np.ndarray, k: int) -> tuple[np.ndarray, ...]:
        """Exact closest points on the faces of the ``k`` nearest proxies of each query.

        Returns ``(proxy distance (q, k), face (q, k), point (q, k, 3), bary (q, k, 3), distance (q, k))``.
        """
        q = len(pts)
        cd, cand = self.tree.query(pts, k=k)
        cand = self.proxy_owner[cand.reshape(q, k)]
        rep = np.repeat(pts, k, axis=0)
        flat = cand.reshape(-1)
        cp, bary = closest_point_on_triangles(rep, self._a[flat], self._b[flat], self._c[flat])
        d = np.linalg.norm(cp - rep, axis=1).reshape(q, k)
        return cd.reshape(q, k), cand, cp.reshape(q, k, 3), bary.reshape(q, k, 3), d

    def _query_k(self, pts: np.ndarray, k: int) -> tuple[ClosestPoints, np.ndarray]:
        """Best face among the ``k`` nearest proxies, and whether it is provably the nearest."""
        cd, cand, cp, bary, d = self._candidates(pts, k)
        best = np.argmin(d, axis=1)
        rows = np.arange(len(pts))
        res = ClosestPoints(cp[rows, best], cand[rows, best].astype(np.int64), bary[rows, best], d[rows, best])
        sure = (cd[:, -1] >= res.distance + self.max_radius) | (k >= self.n_proxies)
        return res, sure

    def _query_aabb(self, pts: np.ndarray) -> ClosestPoints:
        """Exact closest points by the tree (:meth:`_aabb_faces`): the face from the tree, the point
        and its barycentrics recomputed on that face (:func:`closest_point_on_triangles`, our convention)."""
        if not len(pts):
            return ClosestPoints(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0))
        face = self._aabb_faces(pts)
        cp, bary = closest_point_on_triangles(pts, self._a[face], self._b[face], self._c[face])
        return ClosestPoints(cp, face, bary, np.linalg.norm(cp - pts, axis=1))

    def _tree(self) -> Any:
        """libigl's AABB tree of this mesh, built on first use (dropped at exit and from pickles)."""
        if self._aabb is None:
            tree = _igl().AABB()
            tree.init(self.vertices, self.faces)
            self._aabb = tree
            _TREES.add(self)
        return self._aabb

    def _aabb_faces(self, pts: np.ndarray, checked: bool = False) -> np.ndarray:
        """(q,) int64 exact nearest face of each of ``pts (q, 3)`` (q >= 1): by the compiled tree
        of :mod:`proctex.geometry.bvh` (built on first use; ties to the lowest face index), which
        lets go of the GIL, so the parts of a transfer search side by side; by libigl's AABB tree
        where numba does not import. A query that is not finite (a diverged solve's point) gets
        face 0, as it got some face from libigl, instead of stopping the others; ``checked``: the
        caller found every query finite already."""
        if _bvh() is not None:
            if self._bvh is None:
                self._bvh = _bvh().triangle_tree(self.vertices, self.faces)
            pts = np.ascontiguousarray(pts, dtype=np.float64)
            if checked:
                return self._bvh.walk(pts)[0]
            finite = np.isfinite(pts).all(axis=1)
            if finite.all():  # checked here once: the tree's walk takes them as they are
                return self._bvh.walk(pts)[0]
            faces = np.zeros(len(pts), dtype=np.int64)
            if finite.any():
                faces[finite] = self._bvh.walk(np.ascontiguousarray(pts[finite]))[0]
            return faces
        _, face, _ = self._tree().squared_distance(self.vertices, self.faces, np.ascontiguousarray(pts))
        return np.asarray(face, dtype=np.int64)

    @property
    def backend(self) -> str:
        """ "aabb" or "proxies": what answers :meth:`query`."""
        return self._backend

    def query(self, points: np.ndarray, exact: bool = True, k: int | None = None) -> ClosestPoints:
        """Closest surface points of ``points (q, 3)``.

        Exact by default; with the proxy search, ``exact=False`` keeps the best of the first ``k``
        candidates (the index's own ``k`` unless given; cheaper, and right for points near the
        surface; used inside iterative loops and at run time). The AABB backend is always exact.
        """
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"query points must be (q, 3), got {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise ValueError("query points contain NaN or inf")
        if self._backend == "aabb":
            return self._query_aabb(pts)
        k = self.k if k is None else int(min(max(int(k), 1), self.n_proxies))
        res, sure = self._query_k(pts, k)
        if not exact:
            return res
        todo = np.flatnonzero(~sure)
        while len(todo):
            k = min(4 * k, self.n_proxies)
            sub, sub_sure = self._query_k(pts[todo], k)
            res.points[todo], res.faces[todo], res.bary[todo], res.distance[todo] = sub.points, sub.faces, sub.bary, sub.distance
            todo = todo[~sub_sure]
        return res

    def query_facing(self, points: np.ndarray, normals: np.ndarray, k: int = 8, majority: bool = True, max_k: int = 1024) -> ClosestPoints:
        """Nearest surface points on faces whose normal agrees with the query's (``dot > 0``), for
        points on or near the surface that know their side (a face of a mapped part): on a thin
        wall, a point slightly nearer the inside than the outside still lands outside.

        The faces of the first ``k`` proxies are checked, then 4x as many for the queries without a
        facing face among them, up to ``max_k`` (bounded work, unlike :meth:`query_oriented`);
        queries still without one, or with a zero normal, get their plain nearest candidate.
        ``majority``: the queries are one surface whose winding may be the reverse of this mesh's
        (a mirrored member, an inside-out export): when their normals, weighted by length, mostly
        oppose the normals of their nearest faces, all are reversed first.

        With libigl (the ``aabb`` backend) each query's exact nearest face comes first from the AABB
        tree: where it faces the query's way it is the answer (the nearest facing face, exactly, and
        3-4x cheaper than the proxies' candidates); only the other queries go through the proxy
        search above, and one that finds no facing face keeps its exact nearest.

        Args: points (q, 3), normals (q, 3) (any length; zero rows mean "no side").
        """
        pts, nrm = _points_and_normals(points, normals)
        if self._backend == "aabb" and len(pts):
            return self._query_facing_aabb(pts, nrm, k, majority, max_k)
        return self._query_facing_proxies(pts, nrm, k, majority, max_k)

    def facing_faces(self, points: np.ndarray, normals: np.ndarray, k: int = 8, majority: bool = True, max_k: int = 1024) -> np.ndarray:
        """(q,) int64: the faces :meth:`query_facing` answers, without their closest points (the run
        time's UV lookup needs only the face: with the AABB backend the tree's faces are taken as
        they are, and only the queries it does not settle go through the proxy search)."""
        pts, nrm = _points_and_normals(points, normals)
        if self._backend != "aabb" or not len(pts):
            return self._query_facing_proxies(pts, nrm, k, majority, max_k).faces
        faces = self._aabb_faces(pts, checked=True)  # _points_and_normals checked them
        nrm, rest = self._not_facing(faces, nrm, majority)
        if len(rest):
            sub = self._query_facing_proxies(pts[rest], nrm[rest], k, False, max_k).faces
            found = np.einsum("qd,qd->q", self.normals[sub], nrm[rest]) > 0
            faces[rest[found]] = sub[found]
        return faces

    def _not_facing(self, faces: np.ndarray, nrm: np.ndarray, majority: bool) -> tuple[np.ndarray, np.ndarray]:
        """``(normals, rows)``: the query normals (reversed as a whole where ``majority`` and they
        mostly oppose their ``faces (q,)``) and the rows whose face does not face them (zero normals
        excepted): those the proxy search is asked."""
        if _bvh() is not None:  # compiled: one pass
            dots, zero = _bvh().facing_dots(self.normals, faces, nrm)
        else:
            fn = self.normals[faces]
            dots, zero = (fn[:, 0] * nrm[:, 0] + fn[:, 1] * nrm[:, 1]) + fn[:, 2] * nrm[:, 2], ~(np.abs(nrm).sum(axis=1) > 0)
        if majority and dots.sum() < 0:
            nrm, dots = -nrm, -dots
        return nrm, np.flatnonzero((dots <= 0) & ~zero)

    def _query_facing_aabb(self, pts: np.ndarray, nrm: np.ndarray, k: int, majority: bool, max_k: int) -> ClosestPoints:
        """:meth:`query_facing` by the AABB tree first, the proxies for the queries whose exact
        nearest face does not face them."""
        out = self._query_aabb(pts)
        nrm, rest = self._not_facing(out.faces, nrm, majority)
        if len(rest):
            sub = self._query_facing_proxies(pts[rest], nrm[rest], k, False, max_k)
            found = np.einsum("qd,qd->q", self.normals[sub.faces], nrm[rest]) > 0
            sel, r = rest[found], np.flatnonzero(found)
            out.points[sel], out.faces[sel], out.bary[sel], out.distance[sel] = sub.points[r], sub.faces[r], sub.bary[r], sub.distance[r]
        return out

    def _query_facing_proxies(self, pts: np.ndarray, nrm: np.ndarray, k: int, majority: bool, max_k: int) -> ClosestPoints:
        """:meth:`query_facing` by the proxy search alone (checked inputs)."""
        q = len(pts)
        k = int(min(max(int(k), 1), self.n_proxies))
        _, cand, cp, bary, d = self._candidates(pts, k)
        rows = np.arange(q)
        dots = np.einsum("qkd,qd->qk", self.normals[cand], nrm)
        if majority and q and dots[rows, np.argmin(d, axis=1)].sum() < 0:
            nrm, dots = -nrm, -dots
        facing = dots > 0
        best = np.argmin(np.where(facing, d, np.inf), axis=1)
        none = ~facing.any(axis=1)
        best[none] = np.argmin(d[none], axis=1)
        out = ClosestPoints(cp[rows, best], cand[rows, best].astype(np.int64), bary[rows, best], d[rows, best])
        todo = np.flatnonzero(none & (np.abs(nrm).sum(axis=1) > 0))
        while len(todo) and k < min(max_k, self.n_proxies):
            k = min(4 * k, max_k, self.n_proxies)
            _, cand, cp, bary, d = self._candidates(pts[todo], k)
            facing = np.einsum("qkd,qd->qk", self.normals[cand], nrm[todo]) > 0
            found = facing.any(axis=1)
            b = np.argmin(np.where(facing, d, np.inf), axis=1)
            r = np.arange(len(todo))[found]
            sel = todo[found]
            out.points[sel], out.faces[sel], out.bary[sel], out.distance[sel] = cp[r, b[found]], cand[r, b[found]], bary[r, b[found]], d[r, b[found]]
            todo = todo[~found]
        return out

    def query_oriented(self, points: np.ndarray, normals: np.ndarray, min_dot: float = 0.0, k: int = 16, exact: bool = True) -> tuple[ClosestPoints, np.ndarray]:
        """Nearest surface points whose face normal agrees with the query normal.

        A face is admissible for a query when ``dot(face normal, query normal) > min_dot``. The
        faces of the nearest proxies are checked (``k``, then 4k, 16k, ... for the queries not yet
        settled); a query is settled when its closest admissible face is provably the nearest
        admissible one (the same proxy-radius bound as :meth:`query`). This keeps the inside of a
        thin wall from matching its outside. Queries with no admissible face anywhere get their
        plain nearest point. With the AABB backend, a query whose nearest face of all is
        admissible is settled by the tree first (exact, with or without ``exact``).

        Args:
            points: (q, 3) float64; normals: (q, 3) float64 unit query normals.

        Returns:
            ``(ClosestPoints, oriented (q,) bool)``: ``oriented`` is False where no admissible face
            existed (exact otherwise). With ``exact=False`` a query settles on the closest admissible
            face among the first candidates that contain one (cheaper; used inside optimisation loops).
        """
        pts, nrm = _points_and_normals(points, normals)
        q = len(pts)
        out = ClosestPoints(np.zeros((q, 3)), np.zeros(q, np.int64), np.zeros((q, 3)), np.full(q, np.inf))
        oriented = np.zeros(q, dtype=bool)
        todo = np.arange(q)
        if self._backend == "aabb" and q:
            # The nearest face of all, when admissible, is the nearest admissible one (exact): most
            # queries settle here; only the others search the proxies.
            near = self._query_aabb(pts)
            ok = np.einsum("qd,qd->q", self.normals[near.faces], nrm) > min_dot
            out.points[ok], out.faces[ok], out.bary[ok], out.distance[ok] = near.points[ok], near.faces[ok], near.bary[ok], near.distance[ok]
            oriented[ok] = True
            todo = np.flatnonzero(~ok)
        k = int(min(k, self.n_proxies))
        while len(todo):
            cd, cand, cp, bary, d = self._candidates(pts[todo], k)
            ok = np.einsum("qkd,qd->qk", self.normals[cand], nrm[todo]) > min_dot
            d = np.where(ok, d, np.inf)
            best = np.argmin(d, axis=1)
            rows = np.arange(len(todo))
            # Settled: an admissible face whose distance no unexamined face can beat.
            sure = (cd[:, -1] >= d[rows, best] + self.max_radius) | (k >= self.n_proxies) if exact else np.ones(len(todo), dtype=bool)
            found = ok[rows, best] & sure
            sel = todo[found]
            out.points[sel] = cp[rows, best][found]
            out.faces[sel] = cand[rows, best][found]
            out.bary[sel] = bary[rows, best][found]
            out.distance[sel] = d[rows, best][found]
            oriented[sel] = True
            todo = todo[~found]
            if k >= self.n_proxies:
                break
            k = min(4 * k, self.n_proxies)
        if len(todo):
            plain = self.query(pts[todo])
            out.points[todo], out.faces[todo], out.bary[todo], out.distance[todo] = plain.points, plain.faces, plain.bary, plain.distance
        return out, oriented


def interpolate(values: np.ndarray, faces: np.ndarray, face_index: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Barycentric interpolation of per-vertex ``values (n, d)`` at ``(face_index (k,), bary (k, 3))``."""
    return np.einsum("kj,kjd->kd", bary, values[faces[face_index]])
