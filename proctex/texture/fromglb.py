"""A look from a repainted template (issue 53, item 2): the family's own template GLB read back after
a user painted it elsewhere (Blender, Substance Painter, three.js), its textures resampled into the
template's atlases.

Exporters reorder and split vertices, rename, resize and re-encode textures (PNG or JPEG), so faces
are matched by what they are, not by index: every template face finds the file's triangle whose
three corners lie at its corners (within :data:`POSITION_TOL` of the template's size, any corner
order) with the same UVs there (within :data:`UV_TOL`). Each covered texel of a group's atlas then
reads the file's own texture of the matched triangle: the file's texel at its place when the image
has the atlas's size (the UVs agree, so that is the same texel), else the image resampled bilinearly
at the file's UV for that point; the gutter is padded as a painted look's is. A file's PBR maps (metallic-roughness and
normal textures) come along the same way; a material without them keeps the look's maps.

A file is refused (``ValueError``) only when template faces find no triangle at their place or their
UVs differ there, saying how many of each.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FaceMatch", "match_faces", "glb_frame", "textures_from_glb", "POSITION_TOL", "UV_TOL"]

#: how far a file's corner may lie from the template's, as a share of the template's largest side
#: (float32 positions through a viewer's up-axis turn and back stay far inside it).
POSITION_TOL = 2e-5
#: how far a file's UV may lie from the template's (a 2048 texel is 4.9e-4 wide).
UV_TOL = 1e-4
#: the six orders of a triangle's corners: the three turns, then the three of the reversed winding.
_ORDERS = np.array([[0, 1, 2], [1, 2, 0], [2, 0, 1], [0, 2, 1], [2, 1, 0], [1, 0, 2]])


@dataclass
class FaceMatch:
    """Template faces matched to a file's triangles.

    Attributes:
        face: (m,) int64 the file's triangle of each template face (-1: none at its place).
        corner: (m, 3) int64 for each template corner, the file triangle's corner at it.
        missing: template faces no triangle lies at.
        uv_mismatch: template faces a triangle lies at whose UVs differ.
        extra: file triangles no template face took.
        collapsed: template faces without area left unmatched (no triangle needed: they cover no texel).
    """

    face: np.ndarray
    corner: np.ndarray
    missing: int
    uv_mismatch: int
    extra: int
    collapsed: int = 0

    @property
    def ok(self) -> bool:
        return self.missing == 0 and self.uv_mismatch == 0


def glb_frame(vertices: np.ndarray, up: str) -> np.ndarray:
    """(n, 3) the template's vertices where its GLB puts them: turned upright in glTF's +Y-up world by
    the node rotation the exporter writes for ``up`` (:data:`proctex.texture.export.UP_ROTATIONS`)."""
    import pygltflib as gl

    from .export import UP_ROTATIONS
    from .gltf_read import _node_matrix

    if up not in UP_ROTATIONS:
        raise ValueError(f"up must be x, y or z, got {up!r}")
    v = np.asarray(vertices, dtype=np.float64)
    if UP_ROTATIONS[up] is None:
        return v.copy()
    m = _node_matrix(gl.Node(rotation=list(UP_ROTATIONS[up])))
    return v @ m[:3, :3].T + m[:3, 3]


def match_faces(
    tpl_corners: np.ndarray, tpl_uv: np.ndarray, file_corners: np.ndarray, file_uv: np.ndarray, position_tol: float = POSITION_TOL, uv_tol: float = UV_TOL, candidates: int = 8
) -> FaceMatch:
    """Match template faces to a file's triangles by position and UV.

    Args:
        tpl_corners: (m, 3, 3) the template faces' corner positions (in the file's frame: :func:`glb_frame`).
        tpl_uv: (m, 3, 2) their UVs (v up).
        file_corners: (k, 3, 3) and file_uv (k, 3, 2): the file's triangles.
        position_tol: a corner's distance allowed, as a share of the template's largest side.
        uv_tol: a corner's UV distance allowed.
        candidates: how many file triangles nearest a face's centre are tried (coincident faces).
    Returns:
        :class:`FaceMatch` (each file triangle taken at most once).
    """
    from scipy.spatial import cKDTree

    tc = np.asarray(tpl_corners, dtype=np.float64)
    fc = np.asarray(file_corners, dtype=np.float64)
    tu, fu = np.asarray(tpl_uv, dtype=np.float64), np.asarray(file_uv, dtype=np.float64)
    m, k = len(tc), len(fc)
    if tc.shape != (m, 3, 3) or tu.shape != (m, 3, 2) or fc.shape != (k, 3, 3) or fu.shape != (k, 3, 2):
        raise ValueError(f"corners (m, 3, 3) and UVs (m, 3, 2) expected, got {tc.shape}, {tu.shape}, {fc.shape}, {fu.shape}")
    if not (np.isfinite(fc).all() and np.isfinite(fu).all()):
        raise ValueError("the file has non-finite positions or UVs")
    size = max(float(np.ptp(tc.reshape(-1, 3), axis=0).max()), 1e-12)
    tol = position_tol * size
    face = np.full(m, -1, dtype=np.int64)
    corner = np.zeros((m, 3), dtype=np.int64)
    if k == 0:
        return FaceMatch(face, corner, m, 0, 0)
    q = min(candidates, k)
    _, near = cKDTree(fc.mean(axis=1)).query(tc.mean(axis=1), k=q)
    near = near.reshape(m, q)
    taken = np.zeros(k, dtype=bool)
    # each candidate's corners in each of the 6 orders (a reflection reverses the winding; a collapsed
    # triangle has coincident corners, so corners are paired as a whole order, never one by one):
    # the order whose UVs lie nearest among those whose corners all lie at the template's
    at_place = np.zeros((m, q), dtype=bool)
    uv_ok = np.zeros((m, q), dtype=bool)
    pair = np.zeros((m, q, 3), dtype=np.int64)
    for s in range(0, m, 20000):  # bounded temporaries: (chunk, q, 6, 3, 3)
        sl = slice(s, s + 20000)
        cand, cuv = fc[near[sl]][:, :, _ORDERS], fu[near[sl]][:, :, _ORDERS]  # (c, q, 6, 3, 3|2)
        pos = np.linalg.norm(cand - tc[sl, None, None], axis=-1).max(axis=-1)  # (c, q, 6)
        uvd = np.linalg.norm(cuv - tu[sl, None, None], axis=-1).max(axis=-1)
        fits = pos <= tol
        best = np.where(fits, uvd, np.inf).argmin(axis=2)  # (c, q)
        at_place[sl] = fits.any(axis=2)
        uv_ok[sl] = np.take_along_axis(np.where(fits, uvd, np.inf), best[..., None], axis=2)[..., 0] <= uv_tol
        pair[sl] = _ORDERS[best]
    good = at_place & uv_ok
    pending = np.flatnonzero(good.any(axis=1))
    while len(pending):  # the first free candidate of each face; faces that chose the same triangle try again
        free = good[pending] & ~taken[near[pending]]
        has = free.any(axis=1)
        pending = pending[has]
        pick = free[has].argmax(axis=1)
        chosen = near[pending, pick]
        _, first = np.unique(chosen, return_index=True)  # one face per triangle this round
        win = pending[first]
        face[win], corner[win] = chosen[first], pair[win, pick[first]]
        taken[chosen[first]] = True
        pending = np.setdiff1d(pending, win)
    uv_bad = (face < 0) & at_place.any(axis=1)
    # a collapsed face (no area) covers no texel of its own: left unmatched it is said, not refused
    area = np.linalg.norm(np.cross(tc[:, 1] - tc[:, 0], tc[:, 2] - tc[:, 0]), axis=1)
    collapsed = (face < 0) & (area <= tol * tol)
    missing = int(((face < 0) & ~uv_bad & ~collapsed).sum())
    return FaceMatch(face, corner, missing, int((uv_bad & ~collapsed).sum()), int((~taken).sum()), int(collapsed.sum()))


def textures_from_glb(tex_shape, grouping, uv, glb, size: int, base_maps: list | None = None, gutter: int = 8):
    """The look a repainted template GLB holds, in the template's atlases.

    Args:
        tex_shape: the template :class:`proctex.geometry.shape.Shape` in the GLB's frame (:func:`glb_frame`).
        grouping: its grouping; uv: its stored :class:`proctex.texture.uv.ShapeUV`; size: the look's texture side.
        glb: :class:`proctex.texture.gltf_read.TexturedMesh` of the file.
        base_maps: per group the maps to keep where the file's material has none (None: flat maps).
    Returns:
        ``(TemplateTexture, FaceMatch, notes)``. ``ValueError`` when faces or UVs do not match.
    """
    from .paint import GroupTexture, TemplateTexture, group_texels
    from .pbr import PbrMaps, flat_maps
    from .uv import pad_seams, sample_texture

    shape = tex_shape
    corners = shape.vertices[shape.faces]
    file_corners = glb.vertices[glb.faces]
    match = match_faces(corners, uv.corner_uv, file_corners, glb.corner_uv)
    if not match.ok:
        raise ValueError(
            f"the GLB does not hold the family's template: {match.missing} of its {len(shape.faces)} faces have no triangle at "
            f"their place and {match.uv_mismatch} have other UVs there (the template GLB painted elsewhere keeps its "
            f"geometry and UVs; export it again without changing them)"
        )
    notes = []
    if match.extra:
        notes.append(f"{match.extra} triangles of the GLB are not the template's: left out")
    if match.collapsed:
        notes.append(f"{match.collapsed} faces of the template without area found no triangle: their texels are filled from their neighbours")
    texels = group_texels(shape, grouping, uv, size)
    groups = []
    for g, tx in zip(grouping.groups, texels):
        rep = grouping.parts[g.representative]
        tf = rep.faces[tx.face]  # the template face of each covered texel
        held = match.face[tf] >= 0  # not a collapsed face left unmatched
        ff = np.where(held, match.face[tf], 0)
        cuv = glb.corner_uv[ff]  # (t, 3, 2) the file's UVs, reordered to the template's corners
        cuv = np.take_along_axis(cuv, match.corner[tf][..., None].repeat(2, axis=-1), axis=1)
        at = np.einsum("tc,tcd->td", tx.bary, cuv)
        mat = glb.face_group[ff]
        colour = np.zeros((len(tf), 3))
        orm = np.zeros((len(tf), 3))
        normal = np.zeros((len(tf), 3))
        kept = base_maps[g.index] if base_maps is not None and base_maps[g.index] is not None else flat_maps(size, size)
        from_file = np.zeros(len(tf), dtype=bool)

        def read(image: np.ndarray, sel: np.ndarray) -> np.ndarray:
            # the same UVs: at the atlas's own size a texel is the file's texel at its place (exact, also
            # where a tiny face's texel centre lies off the face); at another size, resampled at the UV
            if image.shape[:2] == (size, size):
                px = image[tx.ij[sel, 0], tx.ij[sel, 1], :3]
                return px.astype(np.float64) / 255.0 if px.dtype == np.uint8 else px.astype(np.float64)
            return sample_texture(image, at[sel])[:, :3]

        for mi in np.unique(mat[held]):
            sel = held & (mat == mi)
            colour[sel] = read(glb.textures[mi], sel)
            maps = glb.pbr[mi] if mi < len(glb.pbr) else None
            if maps is not None:
                orm[sel] = read(maps.orm, sel)
                normal[sel] = read(maps.normal, sel)
                from_file[sel] = True
        image = np.full((size, size, 3), 0.5, dtype=np.float32)
        image[tx.ij[:, 0], tx.ij[:, 1]] = colour
        mask = tx.mask.copy()
        mask[tx.ij[~held, 0], tx.ij[~held, 1]] = False
        image, painted = pad_seams(image, mask, gutter)
        painted |= tx.mask
        o, n = kept.orm.copy(), kept.normal.copy()
        if from_file.any():
            ij = tx.ij[from_file]
            o[ij[:, 0], ij[:, 1]] = orm[from_file]
            n[ij[:, 0], ij[:, 1]] = normal[from_file]
            o, _ = pad_seams(o, mask, gutter)
            n, _ = pad_seams(n, mask, gutter)
        pbr = PbrMaps(o.astype(np.float32), n.astype(np.float32), bool(kept.occlusion))
        names = sorted({glb.names[i] for i in np.unique(mat[held])})
        groups.append(GroupTexture(g.index, g.label, f"from GLB material {', '.join(names)[:120]}", image, painted, tx, pbr=pbr))
    return TemplateTexture(shape, grouping, uv, groups, "glb", 0.0, notes), match, notes
