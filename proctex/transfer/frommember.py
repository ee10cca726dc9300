"""A look from any textured member of the family (issue 53, item 3): a GLB of one of the family's
shapes, textured in any UVs, read back into the template's atlases through the family's own
correspondence.

The member is first made a shape of the family: with its parameters, the family's model generates
that shape; without them, the file is read as the family reads any mesh (its parts as a transfer
of it finds them). Each face then takes the file's triangle at its place (:func:`member_surface`,
by position only: the file's UVs may be anything). The member is
then transferred to the template as any shape is (:func:`proctex.transfer.apply.transfer`: its parts
assigned to the template's groups and mapped by the family's networks or cage), which puts every
member triangle where it lands on the template. Each covered texel of a group's atlas takes the
member's colour at the nearest landed triangle of a part of that group (its barycentrics carried
to the member's own UVs, read from the member's texture); texels farther than :data:`COVER_TOL` of
the part's size from any landed triangle are filled from the nearest covered ones on the surface,
and the share filled is reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from proctex.geometry.parts import part_mesh, parts_of
from proctex.geometry.surface import SurfaceIndex, plane_barycentric
from proctex.texture.fromglb import match_faces
from proctex.texture.paint import GroupTexture, TemplateTexture, group_texels
from proctex.texture.paint_loop import fill_unseen
from proctex.texture.pbr import PbrMaps, flat_maps
from proctex.texture.uv import pad_seams, sample_texture, texel_barycentric
from proctex.transfer.apply import transfer

__all__ = ["MemberLook", "member_surface", "textures_from_member", "COVER_TOL"]

#: a template texel is covered when a landed member triangle lies within this share of its part's
#: size (the networks' errors on unseen shapes are about 0.01 of it).
COVER_TOL = 0.03


@dataclass
class MemberLook:
    """What a member gave each group: ``filled`` (group -> share of its covered texels filled from
    neighbours, no member triangle near), ``parts`` (group -> member parts read), ``notes``."""

    filled: dict[int, float] = field(default_factory=dict)
    parts: dict[int, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def filled_share(self) -> float:
        return float(np.mean(list(self.filled.values()))) if self.filled else 1.0


def member_surface(shape, file_frame_vertices: np.ndarray, glb, what: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The member's UVs and materials on ``shape``, a shape of the family standing for it (the model's
    for its parameters, or the file read as the family reads meshes): each face takes the file's
    triangle at its place (:func:`proctex.texture.fromglb.match_faces` by position only).
    ``file_frame_vertices``: the shape's vertices in the file's frame; ``glb`` the file
    (:class:`proctex.texture.gltf_read.TexturedMesh`). Returns ``(corner_uv (m, 3, 2), material (m,),
    matched (m,) bool)`` per face (an unmatched face: material -1); ``ValueError`` naming ``what``
    when under 95 % of the faces find a triangle."""
    corners = np.asarray(file_frame_vertices, dtype=np.float64)[shape.faces]
    match = match_faces(corners, np.zeros((len(corners), 3, 2)), glb.vertices[glb.faces], np.zeros((len(glb.faces), 3, 2)), uv_tol=np.inf)
    ok = match.face >= 0
    if ok.mean() < 0.95:
        raise ValueError(f"the GLB is not {what}: {int((~ok).sum())} of its {len(ok)} faces have no triangle at their place")
    ff = np.where(ok, match.face, 0)
    uv = np.take_along_axis(glb.corner_uv[ff], match.corner[..., None].repeat(2, axis=-1), axis=1)
    return uv, np.where(ok, glb.face_group[ff], -1), ok


def textures_from_member(
    template,
    grouping,
    uv,
    assets,
    member,
    member_uv: np.ndarray,
    member_material: np.ndarray,
    textures: list[np.ndarray],
    mapper,
    size: int,
    seed: int = 0,
    base_maps: list | None = None,
    gutter: int = 8,
    cover_tol: float = COVER_TOL,
):
    """The look a textured member holds, in the template's atlases.

    Args:
        template: the template shape; grouping, uv: its grouping and stored :class:`proctex.texture.uv.ShapeUV`.
        assets: the family's :class:`proctex.transfer.assets.TemplateAssets`; mapper: how it maps parts.
        member: the member :class:`~proctex.geometry.shape.Shape` (the family's frame); member_uv
            (m, 3, 2) and member_material (m,) its faces' UVs and texture (-1: none); textures: its images.
        size: the look's texture side; base_maps: per group the maps to keep (None: flat).
        cover_tol: :data:`COVER_TOL`.
    Returns:
        ``(TemplateTexture, MemberLook)``.
    """
    result = transfer(member, assets, mapper, seed=seed, shortcut=True)
    seg = parts_of(member)
    report = MemberLook(notes=list(result.notes))
    texels = group_texels(template, grouping, uv, size)
    groups = []
    for g, tx in zip(grouping.groups, texels):
        rep = grouping.parts[g.representative]
        rv = template.vertices[rep.vertices]
        scale = max(float(np.ptp(rv, axis=0).max()), 1e-12)
        landed_v, landed_f, owner = [], [], []
        offset = 0
        for a in result.assignment:
            if a.group != g.index or a.part not in result.points:
                continue
            part = seg.parts[a.part]
            _, f = part_mesh(member, part)
            pts = np.asarray(result.points[a.part], dtype=np.float64)
            landed_v.append(pts)
            landed_f.append(f + offset)
            owner.append(part.faces)  # the member's own face of each landed triangle
            offset += len(pts)
        report.parts[g.index] = len(landed_v)
        colour = np.zeros((len(tx.face), 3))
        covered = np.zeros(len(tx.face), dtype=bool)
        if landed_v:
            lv, lf = np.concatenate(landed_v), np.concatenate(landed_f)
            hit = SurfaceIndex(lv, lf).query(tx.points)
            mf = np.concatenate(owner)[hit.faces]
            covered = (hit.distance <= cover_tol * scale) & (member_material[mf] >= 0)
            # the texel's centre itself (its face's plane, past the face's edge for a texel on a chart's
            # border) in the landed triangle's plane: where a texel reads the member, as a painted texel
            # is where its centre lies (a clamped point would read the texel's neighbour)
            centre = _texel_centres(template, rep.faces, uv.corner_uv[rep.faces], tx)
            bary = plane_barycentric(centre, lv[lf[hit.faces]], floor=-1.0)
            at = np.einsum("tc,tcd->td", bary, member_uv[mf])
            for mi in np.unique(member_material[mf][covered]):
                sel = covered & (member_material[mf] == mi)
                colour[sel] = sample_texture(textures[mi], at[sel])[:, :3]
        report.filled[g.index] = float(1.0 - covered.mean()) if len(covered) else 1.0
        if covered.any() and not covered.all():
            colour = fill_unseen(tx.points, colour, covered)
        elif not covered.any():
            colour[:] = 0.5
            report.notes.append(f"group {g.index}: no part of the member lands on it; painted grey")
        image = np.full((size, size, 3), 0.5, dtype=np.float32)
        image[tx.ij[:, 0], tx.ij[:, 1]] = colour
        image, painted = pad_seams(image, tx.mask, gutter)
        kept = base_maps[g.index] if base_maps is not None and base_maps[g.index] is not None else flat_maps(size, size)
        pbr = PbrMaps(kept.orm.copy(), kept.normal.copy(), bool(kept.occlusion))
        groups.append(GroupTexture(g.index, g.label, f"from a member ({report.parts[g.index]} parts, {100 * report.filled[g.index]:.1f}% filled)", image, painted, tx, pbr=pbr))
    return TemplateTexture(template, grouping, uv, groups, "member", 0.0, list(report.notes)), report


def _texel_centres(shape, faces: np.ndarray, corner_uv: np.ndarray, tx) -> np.ndarray:
    """(t, 3) each texel centre on its face's plane (:func:`proctex.texture.uv.texel_barycentric`: a
    border texel's centre may lie past its face's edge), ``faces`` the part's face indices and
    ``corner_uv`` their UVs."""
    bary = texel_barycentric(tx.ij, np.asarray(corner_uv, dtype=np.float64)[tx.face], tx.height, tx.width)
    corners = np.asarray(shape.vertices, dtype=np.float64)[np.asarray(shape.faces)[faces][tx.face]]
    return np.einsum("tc,tcd->td", bary, corners)
