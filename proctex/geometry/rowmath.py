"""Row-wise 3-vector products on ``(m, 3)`` float arrays, the same bits as NumPy's own forms.

``(a * b).sum(1)`` and ``np.cross`` are slow on many short rows (a reduction over a length-3 axis;
``np.cross``'s axis handling): these compute each component with whole-column operations, in the
order NumPy sums and in ``np.cross``'s formula, so the results are equal bit for bit
(``tests/test_geometry.py`` checks both, with and without AVX-512).
"""

from __future__ import annotations

import numpy as np


def dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(m,) row dot products of ``a, b (m, 3)``: ``(a * b).sum(1)``."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(m, 3) float64 row cross products of ``a, b (m, 3)``: ``np.cross(a, b)``."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def bounds(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(points.min(0), points.max(0))`` of ``points (n, d)``, reduced along contiguous memory
    (a reduction down the columns of a C-ordered array walks it with a stride: 10-15x slower on a
    few thousand rows); the values are the same (minima and maxima are exact)."""
    columns = np.ascontiguousarray(np.asarray(points).T)
    return columns.min(axis=1), columns.max(axis=1)
