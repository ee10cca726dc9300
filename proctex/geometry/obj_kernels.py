"""A compiled (numba) reader of the plain OBJ that exporters write (Blender's among them), run on
every OBJ upload a replica serves: one pass over the bytes to count and check the lines, one to
parse them, instead of Arrow's CSV reader, a string pass per group tag and a regular-expression
count of the header.

The plain OBJ this reader takes: lines end in ``\\n`` or ``\\r\\n``; every byte is printable ASCII
(no tabs); ``v x y z`` with three decimal numbers one space apart; ``f a b c`` with three positive
indices, each ``a``, ``a/b``, ``a//c`` or ``a/b/c``; ``o name`` / ``g name`` group lines; ``vt``,
``vn``, ``vp``, ``#``, ``s``, ``usemtl``, ``mtllib`` and ``l`` lines and empty ones ignored. A number
is read only where the float it names is the quotient or product of two exactly representable
numbers (at most 18 significant digits worth less than 2**53, a power of ten up to 22), so it is the
correctly rounded value, bit for bit what Python's ``float`` and Arrow give. Any other file (a quad,
a tab, a relative index, a long number, a non-ASCII name) is not plain: the readers of
:mod:`proctex.geometry.meshio` answer it, with their precise errors. ``tests/test_meshio.py``
compares this reader with them on plain and near-plain files.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: Status codes of :func:`_scan` (0: plain).
PLAIN = 0


@njit(cache=True, nogil=True, inline="always")
def _at_end(buf, j):
    """Whether a line's content ends at ``j``: the end of the buffer, ``\\n`` or ``\\r\\n``."""
    n = buf.shape[0]
    return j == n or buf[j] == 10 or (buf[j] == 13 and j + 1 < n and buf[j + 1] == 10)


_POW10 = np.array([10.0**k for k in range(23)])


@njit(cache=True, nogil=True, inline="always")
def _digits(buf, i, stop, mant, sig):
    """``(next index, mantissa, significant digits, digits read)`` after the decimal digits at
    ``buf[i:stop]``, each appended to ``mant`` (leading zeros are not significant); it stops at
    the 19th significant digit (``sig`` > 18: too long for an exact read)."""
    n = 0
    while i < stop and 48 <= buf[i] <= 57:
        d = buf[i] - 48
        if sig > 0 or d != 0:
            sig += 1
            if sig > 18:
                return i, mant, sig, n
            mant = mant * 10 + d
        n += 1
        i += 1
    return i, mant, sig, n


@njit(cache=True, nogil=True, inline="always")
def _number(buf, i, stop, pow10):
    """``(value, next index, ok)`` of the decimal number at ``buf[i:stop]`` ending at a space, a
    line break or ``stop``; ok is False for anything but ``-?digits[.digits][(e|E)[+-]digits]`` whose value is
    exact by one correctly rounded operation (see the module)."""
    neg = False
    if i < stop and buf[i] == 45:  # -
        neg = True
        i += 1
    i, mant, sig, whole = _digits(buf, i, stop, np.int64(0), 0)
    frac = 0
    if sig <= 18 and i < stop and buf[i] == 46:  # .
        i, mant, sig, frac = _digits(buf, i + 1, stop, mant, sig)
    if sig > 18 or whole + frac == 0:
        return 0.0, i, False
    scale = -frac
    if i < stop and (buf[i] == 101 or buf[i] == 69):  # e E
        i += 1
        eneg = False
        if i < stop and (buf[i] == 43 or buf[i] == 45):
            eneg = buf[i] == 45
            i += 1
        i, e, _, ed = _digits(buf, i, stop, np.int64(0), 0)
        if ed == 0 or ed > 4:
            return 0.0, i, False
        scale += -e if eneg else e
    if i < stop and buf[i] != 32 and buf[i] != 10 and buf[i] != 13:
        return 0.0, i, False
    if mant == 0:
        return (-0.0 if neg else 0.0), i, True
    if mant > 9007199254740992 or scale > 22 or scale < -22:  # 2**53
        return 0.0, i, False
    x = float(mant)
    x = x * pow10[scale] if scale >= 0 else x / pow10[-scale]
    return (-x if neg else x), i, True


@njit(cache=True, nogil=True, inline="always")
def _index(buf, i, stop):
    """``(vertex index, next index, ok)`` of a face corner ``a``, ``a/b``, ``a//c`` or ``a/b/c``
    (digits, ``a`` >= 1, at most 18 significant digits each) at ``buf[i:stop]`` ending at a space, a line break or
    ``stop``."""
    i, v, sig, nd = _digits(buf, i, stop, np.int64(0), 0)
    if sig > 18 or nd == 0 or v < 1:
        return 0, i, False
    slashes = 0
    while i < stop and buf[i] == 47:  # /
        slashes += 1
        if slashes > 2:
            return 0, i, False
        i, _, sig, k = _digits(buf, i + 1, stop, np.int64(0), 0)
        if sig > 18:
            return 0, i, False
        if k == 0 and not (slashes == 1 and i < stop and buf[i] == 47):
            return 0, i, False  # "a/" or "a//" with nothing after; "a//c" passes through here
    if i < stop and buf[i] != 32 and buf[i] != 10 and buf[i] != 13:
        return 0, i, False
    return v, i, True


@njit(cache=True, nogil=True)
def _scan(buf, count_corners):
    """``(status, vertex lines, face lines, group lines, triangles, largest)``: status 0 when every
    byte is printable ASCII or a line break (``\\n``, ``\\r\\n``) and every line's tag is one the
    module takes (``v`` and ``f`` lines are checked fully only by :func:`_parse`), else 1 (and the
    counts 0). ``triangles`` sums each face line's corners less two, ``largest`` is the most
    corners of one (3 without faces): a corner is a run of bytes other than a space; both 0 and 3
    unless ``count_corners``."""
    n = buf.shape[0]
    odd = 0
    for i in range(n):  # no branch: the compiler vectorises it
        c = buf[i]
        odd += ((c < 32) & (c != 10) & (c != 13)) | (c > 126)
    if odd:
        return 1, 0, 0, 0, 0, 0
    for i in range(n):
        if buf[i] == 13 and (i + 1 == n or buf[i + 1] != 10):
            return 1, 0, 0, 0, 0, 0
    nv = 0
    nf = 0
    ng = 0
    triangles = 0
    largest = 0
    for e in range(-1, n - 1):
        if e >= 0 and buf[e] != 10:
            continue
        i = e + 1  # a line starts here
        c = buf[i]
        c2 = buf[i + 1] if i + 1 < n else 10
        if c == 10 or c == 13:  # an empty line
            continue
        if c == 118:  # v
            if c2 == 32:
                nv += 1
            elif not (c2 == 116 or c2 == 110 or c2 == 112):  # vt vn vp
                return 1, 0, 0, 0, 0, 0
        elif c == 102:  # f
            if c2 != 32:
                return 1, 0, 0, 0, 0, 0
            nf += 1
            if not count_corners:  # read_plain: _parse checks each face's three corners
                continue
            corners = 0
            j = i + 1
            while j < n and buf[j] != 10:  # runs of bytes other than space and a break
                corners += (buf[j] != 32) & (buf[j] != 13) & (buf[j - 1] == 32)
                j += 1
            triangles += max(corners - 2, 0)
            largest = max(largest, corners)
        elif c == 111 or c == 103:  # o g
            if c2 != 32:
                return 1, 0, 0, 0, 0, 0
            ng += 1
        elif not (c == 35 or c == 115 or c == 117 or c == 109 or c == 108):  # # s u m l
            return 1, 0, 0, 0, 0, 0
    return 0, nv, nf, ng, triangles, largest if count_corners and nf else 3


@njit(cache=True, nogil=True)
def _parse(buf, nv, nf, ng, pow10):
    """``(status, vertices (nv, 3) float64, faces (nf, 3) int64 0-based, face_group (nf,) int64
    ordinal of the group line before each face or -1, group_span (ng, 2) int64 byte range of each
    group line's name)`` of a buffer :func:`_scan` passed; status 1 when a ``v`` or ``f`` line is not
    plain, else 0."""
    v = np.empty((nv, 3))
    f = np.empty((nf, 3), np.int64)
    fg = np.empty(nf, np.int64)
    span = np.empty((ng, 2), np.int64)
    n = buf.shape[0]
    i = 0
    kv = 0
    kf = 0
    kg = 0
    group = -1
    while i < n:
        c = buf[i]
        c2 = buf[i + 1] if i + 1 < n else 10
        j = i + 2
        if c == 118 and c2 == 32:
            for k in range(3):
                x, j, ok = _number(buf, j, n, pow10)
                if not ok or (k < 2 and (j >= n or buf[j] != 32)):
                    return 1, v, f, fg, span
                v[kv, k] = x
                j += 1
            j -= 1
            if not _at_end(buf, j):
                return 1, v, f, fg, span
            kv += 1
        elif c == 102:
            for k in range(3):
                x, j, ok = _index(buf, j, n)
                if not ok or (k < 2 and (j >= n or buf[j] != 32)):
                    return 1, v, f, fg, span
                f[kf, k] = x - 1  # 0-based
                j += 1
            j -= 1
            if not _at_end(buf, j):
                return 1, v, f, fg, span
            fg[kf] = group
            kf += 1
        elif c == 111 or c == 103:
            j = i + 2
            while j < n and buf[j] != 10:
                j += 1
            span[kg, 0] = i + 2
            span[kg, 1] = j - 1 if j > 0 and buf[j - 1] == 13 else j
            group = kg
            kg += 1
        else:
            j = i
        while j < n and buf[j] != 10:  # to the line's end
            j += 1
        i = j + 1
    return 0, v, f, fg, span


def _buffer(data) -> np.ndarray:
    return np.frombuffer(memoryview(data).cast("B"), dtype=np.uint8)


def plain_counts(data) -> tuple[int, int, int] | None:
    """``(vertex lines, triangles, corners of the largest face)`` of an OBJ's bytes whose bytes and
    line tags are plain (:func:`_scan`; a face line's corners are counted, not checked), or None
    for any other file, which :mod:`proctex.geometry.meshcounts` then counts."""
    status, nv, _, _, triangles, largest = _scan(_buffer(data), True)
    return (int(nv), int(triangles), int(largest)) if status == PLAIN else None


def read_plain(data) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]] | None:
    """``(vertices (n, 3) float64, faces (m, 3) int64 0-based, face_group (m,) int64, names)`` of a
    plain OBJ's bytes, or None for any other file. ``face_group`` is the ordinal of the ``o`` / ``g``
    line before each face (-1 before the first) and ``names`` those lines' names, stripped."""
    buf = _buffer(data)
    status, nv, nf, ng, _, _ = _scan(buf, False)
    if status != PLAIN:
        return None
    status, v, f, fg, span = _parse(buf, nv, nf, ng, _POW10)
    if status != PLAIN:
        return None
    names = [buf[s:e].tobytes().decode("ascii").strip() for s, e in span.tolist()]
    return v, f, fg, names


def warm() -> None:
    """Compile (or load from numba's cache) the reader on a tiny file."""
    read_plain(b"o a\nv 0 0 0\nv 1 0 0\nv 0 1.5e-1 0\nf 1 2 3\n")
