"""Small hand-built meshes for tests."""

import numpy as np

from proctex.geometry import primitives as P


def cube(center=(0.0, 0.0, 0.0), size=1.0):
    """8-vertex closed cube: (vertices (8, 3), faces (12, 3)) with outward winding."""
    part = P.box((size, size, size), center=center)
    return part.vertices, part.faces


def two_cubes_touching():
    """Two unit cubes sharing the face x = 0.5 (coincident vertices, separate indices)."""
    va, fa = cube((0, 0, 0))
    vb, fb = cube((1, 0, 0))
    return np.concatenate([va, vb]), np.concatenate([fa, fb + len(va)])


def soup(vertices, faces):
    """Every face gets its own three vertices (no shared index at all)."""
    return vertices[faces].reshape(-1, 3), np.arange(len(faces) * 3).reshape(-1, 3)


def split_parts(shape):
    """Independent reference for connected components by shared vertex index.

    Returns a list of (vertex ids (k,) int64, local faces (m, 3) int64).
    """
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    f = shape.faces
    n = shape.n_vertices
    adjacency = sp.coo_matrix((np.ones(2 * len(f)), (np.repeat(f[:, 0], 2), f[:, 1:].ravel())), shape=(n, n))
    n_comp, comp = connected_components(adjacency, directed=False)
    parts = []
    for c in range(n_comp):
        ids = np.flatnonzero(comp == c)
        if not np.any(comp[f[:, 0]] == c):
            continue  # an unreferenced vertex is not a part
        local = -np.ones(n, dtype=np.int64)
        local[ids] = np.arange(len(ids))
        parts.append((ids, local[f[comp[f[:, 0]] == c]]))
    return parts


def part_label(shape, ids):
    """The single semantic label of a part's vertices (fails if a part mixes labels)."""
    names = {shape.label_names[i] for i in shape.labels[ids]}
    assert len(names) == 1, f"one part carries several labels: {names}"
    return names.pop()


def labelled_parts(shape):
    """(vertex ids, local faces, label) per part."""
    return [(ids, faces, part_label(shape, ids)) for ids, faces in split_parts(shape)]


def boxes(specs):
    """A shape of axis-aligned boxes, no labels: ``specs`` is [(size (3,), centre (3,))]; each box
    its own part. Returns :class:`proctex.geometry.shape.Shape`."""
    from proctex.geometry.shape import Shape

    vs, fs, n = [], [], 0
    for size, center in specs:
        part = P.box(size, center=center, divisions=(2, 2, 2))
        vs.append(part.vertices)
        fs.append(part.faces + n)
        n += len(part.vertices)
    return Shape(np.concatenate(vs), np.concatenate(fs))


def unlabelled_chair(arms=True, back=True, up="z", scale=1.0):
    """A chair of boxes (seat, four legs, optional back panel and two armrests), no part labels,
    standing on z = 0 (``up="y"``: the same chair turned so that y is up), in units of ``scale``."""
    specs = [((0.5, 0.5, 0.06), (0, 0, 0.47))]
    specs += [((0.05, 0.05, 0.44), (x, y, 0.22)) for x in (-0.22, 0.22) for y in (-0.22, 0.22)]
    if back:
        specs.append(((0.46, 0.05, 0.45), (0, 0.225, 0.75)))
    if arms:
        specs += [((0.06, 0.4, 0.05), (x, 0.0, 0.68)) for x in (-0.28, 0.28)]
    shape = boxes([(np.asarray(s) * scale, np.asarray(c) * scale) for s, c in specs])
    if up == "y":
        shape.vertices = shape.vertices[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0])
    return shape


def unlabelled_table():
    """A table of boxes: top, four legs, a shelf between them; no labels, z up."""
    specs = [((1.2, 0.7, 0.04), (0, 0, 0.73))]
    specs += [((0.05, 0.05, 0.71), (x, y, 0.355)) for x in (-0.55, 0.55) for y in (-0.3, 0.3)]
    specs.append(((1.05, 0.55, 0.02), (0, 0, 0.2)))
    return boxes(specs)


def bent_boxes():
    """A jittered box template ``(vertices, faces)`` and four sources ``[(vertices, faces, seed)]``:
    boxes of other lengths and tessellations bent by 0, 0.1, 0.25 and 0.4 (``z += bend * x^2``), for
    the batched cage solves' tests. Jittered: on exactly perpendicular faces a normal test is a tie
    that float rounding decides either way, in a single solve as in a batch."""
    rng = np.random.default_rng(5)
    t = P.box((1.0, 0.5, 0.4), divisions=(12, 6, 5))
    template = (t.vertices + rng.normal(scale=2e-3, size=t.vertices.shape), t.faces)
    sources = []
    for i, (bend, div) in enumerate(((0.0, (12, 6, 5)), (0.1, (10, 5, 4)), (0.25, (12, 6, 5)), (0.4, (8, 4, 4)))):
        b = P.box((1.0 + 0.2 * i, 0.5, 0.4), divisions=div)
        v = b.vertices + rng.normal(scale=2e-3, size=b.vertices.shape)
        v[:, 2] += bend * v[:, 0] ** 2
        sources.append((v, b.faces, 10 + i))
    return template, sources
