"""Reading a photo for a look (issue 53): :func:`read_photo` turns a photo's bytes into an sRGB
``(H, W, 3)`` float32 image (:class:`Photo`). Its size is checked from the header before any pixel
is decoded (:data:`MAX_PHOTO_PIXELS`, :data:`MAX_PHOTO_BYTES`); corrupt or truncated files, animated
images and formats other than :data:`FORMATS` are refused with a ``ValueError``; alpha, CMYK, 16-bit
greys, palettes and embedded colour profiles are converted, each said in the photo's ``notes``.
:func:`parse_length` reads a photo's physical scale (:data:`UNITS`)."""

from __future__ import annotations

import io
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: the most pixels a photo may have (width x height, read from its header before decoding).
MAX_PHOTO_PIXELS = 40_000_000
#: the most bytes a photo file may have.
MAX_PHOTO_BYTES = 64 * 1024 * 1024
#: the smallest side a photo may have, in pixels.
MIN_PHOTO_SIDE = 16
#: image formats read (Pillow's names); others (EPS, PDF, ...) are refused before decoding.
FORMATS = ("PNG", "JPEG", "WEBP", "TIFF", "BMP", "TGA")
#: the longest side (pixels) a photo is kept at for synthesis: a larger one is resampled (said in its notes).
WORK_SIDE = 512
#: lengths a photo scale may be written in, and their size in metres.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}


# ----------------------------------------------------------------------------------------- reading
@dataclass(frozen=True)
class Photo:
    """A photo read for a look.

    Attributes:
        rgb: ``(H, W, 3)`` float32 sRGB in [0, 1].
        name: where it came from (a file name), for messages.
        notes: what was converted on reading (alpha, CMYK, 16-bit, a colour profile, a resample).
    """

    rgb: np.ndarray
    name: str = "photo"
    notes: tuple[str, ...] = ()

    def png(self) -> bytes:
        """The photo as an 8-bit sRGB PNG (what a look stores)."""
        from PIL import Image

        buf = io.BytesIO()
        Image.fromarray(np.round(np.clip(self.rgb, 0, 1) * 255).astype(np.uint8), "RGB").save(buf, "PNG", optimize=False)
        return buf.getvalue()


def read_photo(source: bytes | str | Path, name: str | None = None, max_pixels: int = MAX_PHOTO_PIXELS, max_bytes: int = MAX_PHOTO_BYTES, work_side: int = WORK_SIDE) -> Photo:
    """Read a photo (a file path or its bytes) into a :class:`Photo`.

    The byte count and the pixel count (from the header, before decoding) are checked first, then the
    format (:data:`FORMATS`) and the frame count (an animated image is refused); the pixels are then
    decoded. Converted and said in ``notes``: an embedded ICC profile (to sRGB), CMYK, 16-bit and
    float greys, palettes and alpha (dropped: a photo is a material, not a cut-out). A photo whose
    longer side exceeds ``work_side`` is resampled to it (Lanczos).

    Raises:
        ValueError: a missing, empty, too large, corrupt, truncated, animated or unsupported file.
    """
    from PIL import Image, UnidentifiedImageError

    label = name or (Path(source).name if isinstance(source, (str, Path)) else "photo")
    label = str(label)[:120]
    if isinstance(source, (str, Path)):
        p = Path(source)
        try:
            size = p.stat().st_size
        except OSError as e:
            raise ValueError(f"cannot read photo {label!r}: {e.strerror or e}") from None
        if not p.is_file():
            raise ValueError(f"photo {label!r} is not a file")
        if size > max_bytes:
            raise ValueError(f"photo {label!r} has {size:,} bytes, over the limit of {max_bytes:,}")
        data = p.read_bytes()
    elif isinstance(source, (bytes, bytearray, memoryview)):
        data = bytes(source)
    else:
        raise ValueError(f"a photo is a file path or bytes, got {type(source).__name__}")
    if not data:
        raise ValueError(f"photo {label!r} is empty")
    if len(data) > max_bytes:
        raise ValueError(f"photo {label!r} has {len(data):,} bytes, over the limit of {max_bytes:,}")
    notes: list[str] = []
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            im = Image.open(io.BytesIO(data), formats=list(FORMATS))
            w, h = im.size
            if w * h > max_pixels:
                raise ValueError(f"photo {label!r} is {w} x {h} pixels, over the limit of {max_pixels:,} (checked before decoding)")
            if min(w, h) < MIN_PHOTO_SIDE:
                raise ValueError(f"photo {label!r} is {w} x {h} pixels; a photo needs at least {MIN_PHOTO_SIDE} a side")
            if getattr(im, "is_animated", False) or getattr(im, "n_frames", 1) > 1:
                raise ValueError(f"photo {label!r} is animated ({getattr(im, 'n_frames', '?')} frames); give one still image")
            im.load()
            rgb = _to_srgb(im, notes)
    except ValueError:
        raise
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as e:
        raise ValueError(f"photo {label!r} has too many pixels, over the limit of {max_pixels:,} (checked before decoding): {e}") from None
    except UnidentifiedImageError as e:
        raise ValueError(f"photo {label!r} is not an image ProcTex reads ({', '.join(FORMATS)}): {e}") from None
    except (OSError, SyntaxError, EOFError, MemoryError, IndexError, TypeError, KeyError, ZeroDivisionError) as e:
        raise ValueError(f"photo {label!r} is corrupt or truncated: {e}") from None
    H, W = rgb.shape[:2]
    if max(H, W) > work_side:
        k = work_side / max(H, W)
        rgb = _resize(rgb, max(1, round(W * k)), max(1, round(H * k)))
        notes.append(f"resampled from {W} x {H} to {rgb.shape[1]} x {rgb.shape[0]} pixels")
    if not np.isfinite(rgb).all():
        raise ValueError(f"photo {label!r} has non-finite pixels")
    return Photo(np.ascontiguousarray(rgb, dtype=np.float32), label, tuple(notes))


def _to_srgb(im: Any, notes: list[str]) -> np.ndarray:
    """A decoded Pillow image -> (H, W, 3) float32 sRGB in [0, 1], saying what was converted."""
    from PIL import Image

    icc = im.info.get("icc_profile")
    if icc:
        try:
            from PIL import ImageCms

            src = ImageCms.ImageCmsProfile(io.BytesIO(icc))
            mode = "RGB" if im.mode in ("RGB", "RGBA", "CMYK", "P", "PA", "LA", "L") else None
            if mode is not None:
                base = im.convert("RGB") if im.mode in ("P", "PA", "LA", "L", "RGBA") else im
                im = ImageCms.profileToProfile(base, src, ImageCms.createProfile("sRGB"), outputMode="RGB")
                notes.append("colour profile converted to sRGB")
        except Exception as e:  # a damaged profile: the pixels are still usable as they are
            notes.append(f"colour profile ignored ({str(e)[:60]})")
    mode = im.mode
    if mode in ("I", "I;16", "I;16B", "I;16L", "I;16N", "F"):
        g = np.asarray(im, dtype=np.float64)
        if mode == "F":
            g = np.nan_to_num(g, nan=0.0, posinf=1.0, neginf=0.0)
            notes.append("float grey clipped to [0, 1]")
        else:
            g = g / 65535.0
            notes.append("16-bit grey converted to 8-bit sRGB range")
        g = np.clip(g, 0.0, 1.0)
        return np.repeat(g[..., None], 3, axis=2).astype(np.float32)
    if mode == "CMYK":
        notes.append("CMYK converted to RGB")
    if mode in ("RGBA", "LA", "PA", "La", "RGBa") or (mode == "P" and "transparency" in im.info):
        a = np.asarray(im.convert("RGBA"), dtype=np.float32)[..., 3]
        notes.append(f"alpha dropped ({float((a < 255).mean()) * 100:.0f}% of pixels not opaque)")
    elif mode == "P":
        notes.append("palette converted to RGB")
    if mode not in ("RGB",):
        im = im.convert("RGB")
    if not isinstance(im, Image.Image):  # pragma: no cover - Pillow always returns images
        raise ValueError("not an image")
    return np.asarray(im, dtype=np.float32) / 255.0


def _resize(rgb: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H, W, C) float image resampled to ``height`` x ``width`` (Lanczos, per channel)."""
    from PIL import Image

    chans = [np.asarray(Image.fromarray(np.ascontiguousarray(rgb[..., c], dtype=np.float32), "F").resize((width, height), Image.LANCZOS)) for c in range(rgb.shape[2])]
    return np.clip(np.stack(chans, axis=2), 0.0, 1.0).astype(np.float32)


def parse_length(text: str | float | int, units: str = "m") -> float:
    """A length as the user writes it, in the family's ``units``: ``0.5`` (already in them), ``"50cm"``,
    ``"0.5 m"``, ``"2in"``. ``ValueError`` for anything else, a non-positive or non-finite value."""
    if units not in UNITS:
        raise ValueError(f"units must be one of {', '.join(UNITS)}, got {str(units)[:20]!r}")
    if isinstance(text, bool):
        raise ValueError(f"a length is a number, got {text!r}")
    if isinstance(text, (int, float)):
        value = float(text)
    else:
        s = str(text).strip().lower()
        unit = next((u for u in sorted(UNITS, key=len, reverse=True) if s.endswith(u)), None)
        num = s[: -len(unit)].strip() if unit else s
        try:
            value = float(num)
        except ValueError:
            raise ValueError(f"a length is a number with an optional unit ({', '.join(UNITS)}), got {str(text)[:40]!r}") from None
        if unit is not None:
            value = value * UNITS[unit] / UNITS[units]
    if not np.isfinite(value) or value <= 0 or value > 1e6:
        raise ValueError(f"a length must be positive and finite (at most 1e6), got {str(text)[:40]!r}")
    return value


# --------------------------------------------------------------------------------------- preparing
