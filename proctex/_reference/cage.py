"""The cage solver's oriented nearest-neighbour match, asking every query for ``k`` neighbours (for tests)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def oriented_nn_reference(tree: cKDTree, pts_normals: np.ndarray, query: np.ndarray, query_normals: np.ndarray, k: int = 8) -> np.ndarray:
    """Index of each query's nearest point (of ``tree``, normals ``pts_normals``) whose normal agrees
    with the query's (positive dot product) among its ``k`` nearest, else its plain nearest."""
    k = min(k, len(pts_normals))
    _, j = tree.query(query, k=k)
    j = np.asarray(j, dtype=np.int64).reshape(len(query), k)
    ok = np.einsum("qkd,qd->qk", pts_normals[j], query_normals) > 0
    first = np.where(ok.any(1), np.argmax(ok, axis=1), 0)
    return j[np.arange(len(query)), first]
