"""Ray-cast rendering of views: cameras, per-pixel geometry buffers and shaded textured images.

Two backends give the same buffers: Embree through trimesh (``embreex`` installed, the fast default)
and a pure NumPy z-buffer rasteriser (:mod:`proctex.geometry.raster`). Both only decide *which triangle* a
pixel sees; the hit point, distance and barycentrics then come from an exact ray-plane intersection,
so the backends agree to rounding wherever they pick the same triangle.

Image conventions: row 0 at the top, pixel ``(i, j)`` centred at ``(j + 0.5, i + 0.5)``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace

import numpy as np

from proctex.geometry.raster import rasterise
from proctex.geometry.surface import face_normals, plane_barycentric

AXES = {"x": 0, "y": 1, "z": 2}


# ---------------------------------------------------------------------------------------- cameras
@dataclass(frozen=True)
class Camera:
    """A pinhole camera. ``eye``, ``target``, ``up``: (3,) float64; vertical field of view in degrees."""

    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov_deg: float = 40.0
    width: int = 512
    height: int = 512
    name: str = ""

    def __post_init__(self) -> None:
        if not 1.0 <= self.fov_deg <= 170.0:
            raise ValueError(f"fov_deg must be in [1, 170], got {self.fov_deg}")
        if self.width < 1 or self.height < 1:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if not (np.isfinite(self.eye).all() and np.isfinite(self.target).all()):
            raise ValueError("camera eye/target must be finite")
        if np.linalg.norm(np.subtract(self.target, self.eye)) <= 0:
            raise ValueError("camera eye and target coincide")

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, forward) unit vectors; ``up`` is re-orthogonalised (any up not parallel to the view)."""
        fwd = np.subtract(self.target, self.eye, dtype=np.float64)
        fwd /= np.linalg.norm(fwd)
        up = np.asarray(self.up, dtype=np.float64)
        right = np.cross(fwd, up)
        if np.linalg.norm(right) < 1e-9:  # looking along up: pick any perpendicular
            right = np.cross(fwd, np.eye(3)[int(np.argmin(np.abs(fwd)))])
        right /= np.linalg.norm(right)
        return right, np.cross(right, fwd), fwd

    @property
    def tan_half(self) -> float:
        return float(np.tan(np.radians(self.fov_deg) / 2))

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Origins and unit directions, each (H*W, 3) float64, row-major over pixels."""
        right, up, fwd = self.basis()
        th, aspect = self.tan_half, self.width / self.height
        xs = ((np.arange(self.width) + 0.5) / self.width * 2 - 1) * th * aspect
        ys = (1 - (np.arange(self.height) + 0.5) / self.height * 2) * th
        gx, gy = np.meshgrid(xs, ys)
        d = fwd + gx.reshape(-1, 1) * right + gy.reshape(-1, 1) * up
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return np.broadcast_to(np.asarray(self.eye, dtype=np.float64), d.shape).copy(), d

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (n, 3) -> pixel coordinates (n, 2) (x = column, y = row) and camera-space depth (n,)."""
        right, up, fwd = self.basis()
        d = np.asarray(points, dtype=np.float64) - np.asarray(self.eye)
        z = d @ fwd
        zs = np.where(z > 1e-12, z, np.nan)
        th, aspect = self.tan_half, self.width / self.height
        x = ((d @ right) / (zs * th * aspect) + 1) / 2 * self.width
        y = (1 - (d @ up) / (zs * th)) / 2 * self.height
        return np.stack([x, y], axis=1), z


def bounding_sphere(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre of the bounding box and half its diagonal: (3,) float64, float (> 0)."""
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0 or not np.isfinite(v).all():
        raise ValueError(f"vertices must be a finite non-empty (n, 3) array, got {v.shape}")
    lo, hi = v.min(axis=0), v.max(axis=0)
    return (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 1e-9)


def up_vector(up: str | np.ndarray) -> np.ndarray:
    """'x' | 'y' | 'z' (optionally '-y' ...) or a vector -> unit (3,) float64."""
    if isinstance(up, str):
        sign = -1.0 if up.startswith("-") else 1.0
        key = up.lstrip("+-").lower()
        if key not in AXES:
            raise ValueError(f"up must be one of x, y, z (optionally signed), got {up!r}")
        return sign * np.eye(3)[AXES[key]]
    v = np.asarray(up, dtype=np.float64)
    if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) == 0:
        raise ValueError(f"up must be a non-zero (3,) vector, got {up!r}")
    return v / np.linalg.norm(v)


def default_up(source: str) -> str:
    """Up axis by convention of where a shape came from: OBJ/glTF files are y-up, everything else z-up."""
    ext = os.path.splitext(str(source))[1].lower()
    return "y" if ext in (".obj", ".glb", ".gltf") else "z"


def _frame(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors (front, side) completing ``up`` to a right-handed frame.

    Blender's conventions: z-up shapes are seen from -y in the front view; y-up shapes (OBJ/glTF
    exports, where Blender's -y became +z) from +z; otherwise the first axis not along ``up``.
    """
    k = int(np.argmax(np.abs(up)))
    front = {2: -np.eye(3)[1], 1: np.eye(3)[2]}.get(k, np.eye(3)[1])
    front = front - up * (front @ up)
    front /= np.linalg.norm(front)
    return front, np.cross(up, front)


def orbit_camera(center, radius, up, azimuth: float, elevation: float, size: int = 512, fov_deg: float = 40.0, name: str = "") -> Camera:
    """Camera on a sphere around ``center`` looking at it, fitting a sphere of ``radius`` in view.

    Azimuth is measured from the shape's front around ``up`` (degrees), elevation above the horizon.
    """
    upv = up_vector(up)
    front, side = _frame(upv)
    az, el = np.radians(azimuth), np.radians(elevation)
    direction = np.cos(el) * (np.cos(az) * front + np.sin(az) * side) + np.sin(el) * upv
    dist = float(radius) / np.sin(np.radians(fov_deg) / 2) * 1.02
    eye = np.asarray(center, dtype=np.float64) + direction * dist
    cam_up = upv if abs(np.sin(el)) < 0.999 else -np.sign(np.sin(el)) * front
    return Camera(tuple(eye), tuple(np.asarray(center, float)), tuple(cam_up), fov_deg, size, size, name)


def canonical_cameras(center, radius, up="z", size: int = 512, fov_deg: float = 40.0) -> list[Camera]:
    """The six canonical views (docs/results.md): front, back, left, right, top, bottom."""
    views = [("front", 0, 0), ("back", 180, 0), ("left", -90, 0), ("right", 90, 0), ("top", 0, 90), ("bottom", 0, -90)]
    return [orbit_camera(center, radius, up, az, el, size, fov_deg, name) for name, az, el in views]


def orbit_path(center, radius, up="z", n: int = 11, size: int = 512, fov_deg: float = 40.0) -> list[Camera]:
    """An InTex-like paint path: front first, then around at 15°, then high and low views.

    With ``n = 11``: 8 views every 45° at 15° elevation, two high views (60°, front and back) and one
    from below (-50°). Other ``n`` scale the ring (at least 3 views).
    """
    if n < 3:
        raise ValueError(f"an orbit path needs at least 3 views, got {n}")
    ring = max(n - 3, 3) if n >= 6 else n
    views = [(360.0 * k / ring, 15.0) for k in range(ring)]
    extra = [(30.0, 60.0), (210.0, 60.0), (120.0, -50.0)][: n - ring]
    # Alternate sides so early views cover opposite halves (the first views generate the most).
    order = sorted(range(ring), key=lambda k: (k % 2, k))
    views = [views[k] for k in order] + extra
    return [orbit_camera(center, radius, up, az, el, size, fov_deg, f"orbit{i}") for i, (az, el) in enumerate(views)]


def turntable(center, radius, up="z", n: int = 24, elevation: float = 20.0, size: int = 512, fov_deg: float = 40.0) -> list[Camera]:
    """``n`` views evenly around ``up`` at a fixed elevation."""
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    return [orbit_camera(center, radius, up, 360.0 * k / n, elevation, size, fov_deg, f"turn{k}") for k in range(n)]


# ---------------------------------------------------------------------------------------- tracing
def embree_available() -> bool:
    try:
        import trimesh

        return bool(trimesh.ray.has_embree)
    except Exception:  # pragma: no cover
        return False


class Tracer:
    """Finds the triangle each camera pixel sees. Build once per mesh, trace many cameras.

    ``backend``: "embree" (trimesh + embreex), "raster" (pure NumPy z-buffer) or "auto".
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, backend: str = "auto") -> None:
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
            raise ValueError(f"vertices must be a finite (n, 3) array, got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or f.min() < 0 or f.max() >= len(v):
            raise ValueError("faces must be a non-empty (m, 3) array indexing the vertices")
        if backend not in ("auto", "embree", "raster"):
            raise ValueError(f"backend must be auto, embree or raster, got {backend!r}")
        if backend == "auto":
            backend = "embree" if embree_available() else "raster"
        if backend == "embree" and not embree_available():
            raise ValueError("embree backend requested but embreex is not installed")
        self.vertices, self.faces, self.backend = v, f, backend
        self.normals = face_normals(v, f)
        self._intersector = None
        if backend == "embree":
            import trimesh
            from trimesh.ray.ray_pyembree import RayMeshIntersector

            self._intersector = RayMeshIntersector(trimesh.Trimesh(v, f, process=False, validate=False))

    def faces_seen(self, camera: Camera, rays: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """(H, W) int64 face index per pixel, -1 where the ray misses. ``rays``: the camera's
        :meth:`Camera.rays`, when the caller has them already."""
        H, W = camera.height, camera.width
        if self.backend == "embree":
            origins, dirs = rays if rays is not None else camera.rays()
            tri, ray = self._intersector.intersects_id(origins, dirs, multiple_hits=False)
            out = np.full(H * W, -1, dtype=np.int64)
            out[ray] = tri
            return out.reshape(H, W)
        xy, z = camera.project(self.vertices)
        tri_z = z[self.faces]
        front = (tri_z > 1e-9).all(axis=1)  # cameras sit outside the shape; drop anything behind the eye
        idx = np.flatnonzero(front)
        # 1/z is affine in screen space: rasterise -1/z so that the nearest fragment is the smallest.
        face, _ = rasterise(xy[self.faces[idx]], H, W, depth=-1.0 / tri_z[idx])
        return np.where(face >= 0, idx[np.maximum(face, 0)], -1)


@dataclass
class Buffers:
    """Per-pixel geometry of one view (H x W, row 0 at the top); background pixels hold -1 / inf / 0.

    Attributes:
        camera: the camera.
        face: (H, W) int64 triangle id; part: (H, W) int64 part id; group: (H, W) int64 group id.
        bary: (H, W, 3) float64 barycentrics of the hit in its triangle.
        depth: (H, W) float64 distance from the eye along the ray (inf on background).
        points: (H, W, 3) float64 hit points.
        normal: (H, W, 3) float64 unit face normals turned towards the camera.
        cos: (H, W) float64 cosine between that normal and the direction to the eye (0 on background).
    """

    camera: Camera
    face: np.ndarray
    part: np.ndarray
    group: np.ndarray
    bary: np.ndarray
    depth: np.ndarray
    points: np.ndarray
    normal: np.ndarray
    cos: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool pixels that see the surface."""
        return self.face >= 0


def render_buffers(
    tracer: Tracer,
    camera: Camera,
    face_part: np.ndarray | None = None,
    face_group: np.ndarray | None = None,
) -> Buffers:
    """Geometry buffers of one view. ``face_part``/``face_group``: optional (m,) int64 labels per face."""
    m = len(tracer.faces)
    for name, arr in (("face_part", face_part), ("face_group", face_group)):
        if arr is not None and np.shape(arr) != (m,):
            raise ValueError(f"{name} must be ({m},), got {np.shape(arr)}")
    H, W = camera.height, camera.width
    origins, dirs = camera.rays()
    face = tracer.faces_seen(camera, (origins, dirs))
    hit = np.flatnonzero(face.ravel() >= 0)
    f = face.ravel()[hit]
    tri = tracer.vertices[tracer.faces[f]]
    n = tracer.normals[f]
    d = dirs[hit]
    o = origins[hit]
    # Exact ray-plane intersection with the seen triangle.
    denom = np.einsum("ij,ij->i", d, n)
    safe = np.where(np.abs(denom) > 1e-15, denom, 1e-15)
    t = np.einsum("ij,ij->i", tri[:, 0] - o, n) / safe
    bad = (np.abs(denom) <= 1e-15) | ~np.isfinite(t)
    if bad.any():  # grazing hit on a (nearly) edge-on triangle: fall back to its centroid distance
        t[bad] = np.linalg.norm(tri[bad].mean(axis=1) - o[bad], axis=1)
    p = o + d * t[:, None]
    lam = plane_barycentric(p, tri)
    depth = np.full(H * W, np.inf)
    depth[hit] = t
    points = np.zeros((H * W, 3))
    points[hit] = p
    bary = np.zeros((H * W, 3))
    bary[hit] = lam
    flip = np.where(denom > 0, -1.0, 1.0)[:, None]
    normal = np.zeros((H * W, 3))
    normal[hit] = n * flip
    cos = np.zeros(H * W)
    cos[hit] = np.abs(denom)
    part = np.full(H * W, -1, dtype=np.int64)
    group = np.full(H * W, -1, dtype=np.int64)
    if face_part is not None:
        part[hit] = np.asarray(face_part)[f]
    if face_group is not None:
        group[hit] = np.asarray(face_group)[f]
    shape2, shape3 = (H, W), (H, W, 3)
    return Buffers(
        camera,
        face.reshape(shape2),
        part.reshape(shape2),
        group.reshape(shape2),
        bary.reshape(shape3),
        depth.reshape(shape2),
        points.reshape(shape3),
        normal.reshape(shape3),
        cos.reshape(shape2),
    )


def with_labels(buffers: Buffers, face_part: np.ndarray | None = None, face_group: np.ndarray | None = None) -> Buffers:
    """The same view with other per-face labels (``face_part``/``face_group``: (m,) int64 over the
    traced mesh's faces; -1 where absent): one tracing serves every UV layout of a mesh."""
    hit = buffers.mask
    f = buffers.face[hit]
    labels = {}
    for name, arr in (("part", face_part), ("group", face_group)):
        out = np.full(buffers.face.shape, -1, dtype=np.int64)
        if arr is not None:
            arr = np.asarray(arr, dtype=np.int64)
            if arr.ndim != 1 or (len(f) and f.max() >= len(arr)):
                raise ValueError(f"face_{name} must label every face of the traced mesh, got {arr.shape}")
            out[hit] = arr[f]
        labels[name] = out
    return replace(buffers, **labels)


def canonical_buffers(vertices: np.ndarray, faces: np.ndarray, up="z", size: int = 512, tracer: Tracer | None = None) -> list[Buffers]:
    """Geometry buffers (no labels) of the six canonical views (:func:`canonical_cameras` of the
    bounding sphere of ``vertices (n, 3)``) of the mesh ``faces (m, 3)``: traced once, they serve
    :func:`proctex.texture.metrics.coverage` and :func:`render_six_views` of every UV layout and
    texture set of that mesh (:func:`with_labels`)."""
    tracer = tracer if tracer is not None else Tracer(vertices, faces)
    c, r = bounding_sphere(vertices)
    return [render_buffers(tracer, cam) for cam in canonical_cameras(c, r, up, size)]


def check_views(views: list[Buffers], n_faces: int, size: int) -> list[Buffers]:
    """``views`` (traced six canonical views) checked against a mesh of ``n_faces`` faces and a view size."""
    if len(views) != 6 or any(b.face.shape != (size, size) or int(b.face.max()) >= n_faces for b in views):
        raise ValueError(f"views must be the six canonical {size}x{size} views of this mesh (canonical_buffers)")
    return views


# ---------------------------------------------------------------------------------------- shading
def pixel_uv(buffers: Buffers, corner_uv: np.ndarray) -> np.ndarray:
    """(H, W, 2) UV of each pixel from per-corner UVs (m, 3, 2) (0 on background)."""
    H, W = buffers.face.shape
    out = np.zeros((H, W, 2))
    m = buffers.mask
    out[m] = np.einsum("ij,ijk->ik", buffers.bary[m], np.asarray(corner_uv)[buffers.face[m]])
    return out


def textured_albedo(buffers: Buffers, corner_uv: np.ndarray, face_group: np.ndarray, textures: list[np.ndarray], default=(0.7, 0.7, 0.7)) -> np.ndarray:
    """(H, W, 3) float64 colour per pixel: bilinear texture lookup in the pixel's group texture."""
    from .uv import sample_texture

    H, W = buffers.face.shape
    out = np.zeros((H, W, 3))
    m = buffers.mask
    out[m] = default
    uv = pixel_uv(buffers, corner_uv)
    fg = np.asarray(face_group)
    for g, tex in enumerate(textures):
        sel = m & (fg[np.maximum(buffers.face, 0)] == g)
        if sel.any():
            out[sel] = sample_texture(tex, uv[sel])[:, :3]
    return out


def shade(buffers: Buffers, albedo: np.ndarray, background=(1.0, 1.0, 1.0), ambient: float = 0.35) -> np.ndarray:
    """(H, W, 3) uint8 image: albedo lit by a headlight (ambient + diffuse by view cosine)."""
    img = np.empty(albedo.shape, dtype=np.float64)
    img[:] = background
    m = buffers.mask
    lit = ambient + (1 - ambient) * buffers.cos[m]
    img[m] = np.asarray(albedo)[m] * lit[:, None]
    return (np.clip(img, 0, 1) * 255).round().astype(np.uint8)


def save_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an (H, W, 3|4) uint8 (or float in [0, 1]) image as PNG, atomically."""
    from proctex.fileio import atomic_write, encode_png

    atomic_write(path, encode_png(image))


def render_textured(
    vertices: np.ndarray,
    faces: np.ndarray,
    corner_uv: np.ndarray,
    face_group: np.ndarray,
    textures: list[np.ndarray],
    camera: Camera,
    tracer: Tracer | None = None,
    background=(1.0, 1.0, 1.0),
    maps: list | None = None,
    normals: np.ndarray | None = None,
    buffers: Buffers | None = None,
) -> np.ndarray:
    """(H, W, 3) uint8 shaded image of a textured mesh seen by ``camera``.

    ``vertices (n, 3)``, ``faces (m, 3)``, ``corner_uv (m, 3, 2)``, ``face_group (m,)`` indexing
    ``textures`` (each (H, W, 3|4) uint8 or float). ``tracer``: reuse one built for this mesh.
    ``maps``: per texture its :class:`proctex.texture.pbr.PbrMaps` or None; with any, the view is lit
    physically (:mod:`proctex.texture.lighting`: roughness, metalness and normal maps under lights
    and a studio environment), else by the headlight of :func:`shade`; ``normals``: (m, 3, 3)
    per-corner normals for that lighting (default: smooth vertex normals). ``buffers``: the view
    traced already (this camera's, of this mesh: :func:`canonical_buffers`); nothing is traced.
    """
    if buffers is not None:
        if np.shape(face_group) != (len(faces),):
            raise ValueError(f"face_group must be ({len(faces)},), got {np.shape(face_group)}")
        b = with_labels(buffers, face_group=face_group)
    else:
        tracer = tracer if tracer is not None else Tracer(vertices, faces)
        b = render_buffers(tracer, camera, face_group=np.asarray(face_group))
    if maps is not None and any(m is not None for m in maps):
        from .lighting import pbr_surface, shade_pbr

        return shade_pbr(b, pbr_surface(b, vertices, faces, corner_uv, face_group, textures, maps, normals), background=background)
    return shade(b, textured_albedo(b, corner_uv, face_group, textures), background=background)


# ---------------------------------------------------------------------------------------- views of textured meshes
THREE_QUARTER = (-35.0, 25.0)  # azimuth, elevation (degrees) of the default 3/4 view


def three_quarter_camera(vertices: np.ndarray, up="z", size: int = 512, azimuth: float = THREE_QUARTER[0], elevation: float = THREE_QUARTER[1], fov_deg: float = 40.0) -> Camera:
    """A (size x size) 3/4 view camera framing the bounding sphere of ``vertices`` (n, 3).

    ``up``: 'x' | 'y' | 'z' (optionally signed) or a (3,) vector; azimuth from the front, elevation
    above the horizon, in degrees.
    """
    c, r = bounding_sphere(vertices)
    return orbit_camera(c, r, up, azimuth, elevation, size, fov_deg, "three_quarter")


def render_views(
    vertices: np.ndarray,
    faces: np.ndarray,
    corner_uv: np.ndarray,
    face_group: np.ndarray,
    textures: list[np.ndarray],
    cameras: list[Camera],
    tracer: Tracer | None = None,
    background=(1.0, 1.0, 1.0),
    maps: list | None = None,
    normals: np.ndarray | None = None,
    buffers: list[Buffers] | None = None,
) -> list[np.ndarray]:
    """Shaded textured images, one (H, W, 3) uint8 per camera (inputs as in :func:`render_textured`).

    One :class:`Tracer` is built for all cameras (or ``tracer`` is reused); ``buffers``: the
    cameras' views traced already (one per camera), then nothing is traced.
    """
    if buffers is not None:
        if len(buffers) != len(cameras):
            raise ValueError(f"buffers must hold one traced view per camera: {len(buffers)} for {len(cameras)}")
        return [render_textured(vertices, faces, corner_uv, face_group, textures, cam, None, background, maps, normals, b) for cam, b in zip(cameras, buffers)]
    tracer = tracer if tracer is not None else Tracer(vertices, faces)
    return [render_textured(vertices, faces, corner_uv, face_group, textures, cam, tracer, background, maps, normals) for cam in cameras]


def render_three_quarter(
    vertices: np.ndarray,
    faces: np.ndarray,
    corner_uv: np.ndarray,
    face_group: np.ndarray,
    textures: list[np.ndarray],
    up="z",
    size: int = 512,
    tracer: Tracer | None = None,
    maps: list | None = None,
    normals: np.ndarray | None = None,
) -> np.ndarray:
    """(size, size, 3) uint8 image of the textured mesh from the 3/4 view (:func:`three_quarter_camera`)."""
    cam = three_quarter_camera(vertices, up, size)
    return render_views(vertices, faces, corner_uv, face_group, textures, [cam], tracer, maps=maps, normals=normals)[0]


def render_six_views(
    vertices: np.ndarray,
    faces: np.ndarray,
    corner_uv: np.ndarray,
    face_group: np.ndarray,
    textures: list[np.ndarray],
    up="z",
    size: int = 512,
    tracer: Tracer | None = None,
    maps: list | None = None,
    normals: np.ndarray | None = None,
    views: list[Buffers] | None = None,
) -> tuple[list[np.ndarray], list[str]]:
    """The six canonical views (:func:`canonical_cameras`): six (size, size, 3) uint8 images and their
    names. ``views``: those views of this mesh traced already (:func:`canonical_buffers`)."""
    c, r = bounding_sphere(vertices)
    cams = canonical_cameras(c, r, up, size)
    views = check_views(views, len(faces), size) if views is not None else None
    return render_views(vertices, faces, corner_uv, face_group, textures, cams, tracer, maps=maps, normals=normals, buffers=views), [cam.name for cam in cams]


def turntable_frames(
    vertices: np.ndarray,
    faces: np.ndarray,
    corner_uv: np.ndarray,
    face_group: np.ndarray,
    textures: list[np.ndarray],
    up="z",
    n: int = 24,
    size: int = 512,
    elevation: float = 20.0,
    tracer: Tracer | None = None,
    maps: list | None = None,
    normals: np.ndarray | None = None,
) -> list[np.ndarray]:
    """``n`` (size, size, 3) uint8 frames around ``up`` (:func:`turntable`), starting at the front."""
    c, r = bounding_sphere(vertices)
    cams = turntable(c, r, up, n, elevation, size)
    return render_views(vertices, faces, corner_uv, face_group, textures, cams, tracer, maps=maps, normals=normals)


def _font(height: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=height)
    except TypeError:  # Pillow < 10.1: fixed-size bitmap font
        return ImageFont.load_default()


def render_grid(images: list[np.ndarray], cols: int, labels: list[str] | None = None, pad: int = 4, background: int = 255) -> np.ndarray:
    """Tile equally sized (h, w, 3) uint8 images row-major into ``cols`` columns with ``pad`` pixels between.

    ``labels``: one caption per image, drawn centred in a band above each tile (PIL default font).
    Returns (rows * (band + h + pad) + pad, cols * (w + pad) + pad, 3) uint8, with
    ``rows = ceil(len(images) / cols)``; missing tiles of the last row stay background.
    """
    if not images:
        raise ValueError("render_grid needs at least one image")
    if cols < 1:
        raise ValueError(f"cols must be >= 1, got {cols}")
    h, w = np.asarray(images[0]).shape[:2]
    for k, im in enumerate(images):
        im = np.asarray(im)
        if im.dtype != np.uint8 or im.shape != (h, w, 3):
            raise ValueError(f"images[{k}]: expected a ({h}, {w}, 3) uint8 image, got {im.dtype} {im.shape}")
    if labels is not None and len(labels) != len(images):
        raise ValueError(f"need one label per image ({len(images)}), got {len(labels)}")
    band = max(10, min(h // 12, 28)) if labels is not None else 0
    rows = -(-len(images) // cols)
    out = np.full((rows * (band + h + pad) + pad, cols * (w + pad) + pad, 3), background, np.uint8)
    for k, im in enumerate(images):
        y, x = pad + (k // cols) * (band + h + pad) + band, pad + (k % cols) * (w + pad)
        out[y : y + h, x : x + w] = im
    if labels is not None:
        from PIL import Image, ImageDraw

        pil = Image.fromarray(out)
        draw, font = ImageDraw.Draw(pil), _font(max(8, int(band * 0.8)))
        for k, text in enumerate(labels):
            cx = pad + (k % cols) * (w + pad) + w / 2
            cy = pad + (k // cols) * (band + h + pad) + band / 2
            draw.text((cx, cy), str(text), fill=(40, 40, 40), font=font, anchor="mm")
        out = np.asarray(pil).copy()
    return out


def grid_columns(n: int) -> int:
    """A pleasant number of columns for ``n`` tiles (about 3:2 landscape): 6 -> 3, 24 -> 6."""
    return int(min(n, max(1, round(np.sqrt(n * 1.5)))))


def save_gif(path: str | os.PathLike, frames: list[np.ndarray], fps: float = 12.0, loop: int = 0) -> None:
    """Write equally sized (H, W, 3) uint8 frames as an animated GIF (``loop`` 0: forever), atomically."""
    from PIL import Image

    if not frames:
        raise ValueError("save_gif needs at least one frame")
    if not 0 < fps <= 100:
        raise ValueError(f"fps must be in (0, 100], got {fps}")
    shape = np.asarray(frames[0]).shape
    ims = []
    for k, f in enumerate(frames):
        f = np.asarray(f)
        if f.dtype != np.uint8 or f.ndim != 3 or f.shape[2] != 3 or f.shape != shape:
            raise ValueError(f"frames[{k}]: expected a {shape} uint8 (H, W, 3) image, got {f.dtype} {f.shape}")
        ims.append(Image.fromarray(f))
    import io

    from proctex.fileio import atomic_write

    buf = io.BytesIO()
    ims[0].save(buf, format="GIF", save_all=True, append_images=ims[1:], duration=max(10, round(1000 / fps)), loop=loop, disposal=1)
    atomic_write(path, buf.getvalue())
