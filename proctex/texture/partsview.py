"""A picture of which part group took which part word (``proctex parts FAMILY --png``): the template
in one flat colour per group from two sides, each group's number and word written on it where it
shows most, and a legend of every group (word, how it got it, score, the text it is painted with)."""

from __future__ import annotations

from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from proctex.geometry.preview import PALETTE
from proctex.texture.render import Tracer, bounding_sphere, orbit_camera, render_buffers, shade

#: views: (azimuth, elevation) in degrees, front-right and back-left, both from above
VIEWS = ((35.0, 25.0), (215.0, 25.0))
#: legend lines drawn at most (the rest counted)
MAX_LEGEND = 40


def group_colors(n: int) -> np.ndarray:
    """``(n, 3) float`` colours in [0, 1], one per group: the preview palette, darkened per round."""
    k = np.arange(n)
    return PALETTE[k % len(PALETTE)] * (0.85 ** (k // len(PALETTE)))[:, None]


def _tag(row: dict[str, Any]) -> str:
    """``"3 legs 0.92"``; a group no word took shows the vocabulary's best word for it with "?"."""
    looks = row.get("looks_like") or []
    word = row.get("word") or (f"{looks[0][0]}?" if looks else "-")
    score = row.get("score")
    return f"{row['group']} {word}" + (f" {score:.2f}" if isinstance(score, (int, float)) else "")


def parts_picture(vertices: np.ndarray, faces: np.ndarray, face_group: np.ndarray, report: dict[str, Any], up: str = "z", size: int = 400) -> Image.Image:
    """The picture (RGB): ``vertices (n, 3) float``, ``faces (m, 3) int``, ``face_group (m,) int``
    (-1: no group), ``report`` as :func:`proctex.texture.painters.partwords.parts_report` makes it,
    ``up`` the shape's up axis, ``size`` pixels per view (64-2048)."""
    if not isinstance(size, int) or isinstance(size, bool) or not 64 <= size <= 2048:
        raise ValueError(f"size must be an integer in [64, 2048], got {size!r}")
    fg = np.asarray(face_group, dtype=np.int64)
    if fg.shape != (len(faces),):
        raise ValueError(f"face_group must be ({len(faces)},), got {fg.shape}")
    rows = list(report.get("groups", []))
    colors = group_colors(max(len(rows), int(fg.max(initial=-1)) + 1, 1))
    tracer = Tracer(np.asarray(vertices, dtype=np.float64), np.asarray(faces))
    c, r = bounding_sphere(np.asarray(vertices, dtype=np.float64))
    views, seen = [], []
    for az, el in VIEWS:
        b = render_buffers(tracer, orbit_camera(c, r, up, az, el, size), face_group=fg)
        albedo = np.full((size, size, 3), 0.7)
        hit = b.mask & (b.group >= 0)
        albedo[hit] = colors[b.group[hit]]
        views.append(shade(b, albedo))
        seen.append(np.where(b.mask, b.group, -1))
    by_row = {int(row["group"]): row for row in rows}
    legend = [
        f"{row['group']:>3}  {(row.get('word') or '-')[:24]:<24} {row.get('how', ''):<6} "
        + (f"{row['score']:.2f}" if isinstance(row.get("score"), (int, float)) else "    ")
        + f"  {str(row.get('text', ''))[:60]!r}"
        for row in rows[:MAX_LEGEND]
    ]
    if len(rows) > MAX_LEGEND:
        legend.append(f"... and {len(rows) - MAX_LEGEND} more groups (the JSON has them all)")
    head = f"prompt: {str(report.get('prompt', ''))[:110]!r}" + (f"  (read for {report['kind']})" if report.get("kind") else "")
    line_h = 13
    canvas = Image.new("RGB", (2 * size, size + line_h * (len(legend) + 2) + 8), "white")
    for k, img in enumerate(views):
        canvas.paste(Image.fromarray(img), (k * size, 0))
    draw = ImageDraw.Draw(canvas)
    # each group's tag where it shows most: the middle of its pixels in the view showing most of it
    for gid in sorted(by_row):
        counts = [int((s == gid).sum()) for s in seen]
        k = int(np.argmax(counts))
        if counts[k] == 0:
            continue
        ys, xs = np.nonzero(seen[k] == gid)
        i = int(np.argmin((ys - np.median(ys)) ** 2 + (xs - np.median(xs)) ** 2))  # a pixel of the group near its middle
        text = _tag(by_row[gid])
        x, y = k * size + int(xs[i]), int(ys[i])
        w = draw.textlength(text)
        x0 = min(max(x - w / 2, k * size + 1), (k + 1) * size - w - 3)
        draw.rectangle((x0 - 2, y - 7, x0 + w + 2, y + 7), fill=(255, 255, 255), outline=tuple(int(v * 255) for v in colors[gid]))
        draw.text((x0, y - 6), text, fill=(10, 10, 10))
    y = size + 4
    draw.text((4, y), head, fill=(10, 10, 10))
    for k, line in enumerate(legend):
        gid = rows[k]["group"] if k < len(rows[:MAX_LEGEND]) else None
        if gid is not None:
            draw.rectangle((4, y + line_h * (k + 1) + 2, 12, y + line_h * (k + 1) + 10), fill=tuple(int(v * 255) for v in colors[int(gid)]))
        draw.text((16, y + line_h * (k + 1)), line, fill=(10, 10, 10))
    return canvas
