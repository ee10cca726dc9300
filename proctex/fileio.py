"""Local file writes and image encoding, each in one place: atomic writes (a temporary file next to
the target, then a rename, so a reader never sees half a file and a crash leaves the old one) and
PNG encoding. The family store (:mod:`proctex.store.layout`) does its own atomic writes through pyarrow's
file systems, which also reach object stores."""

from __future__ import annotations

import io
import os
import tempfile
from pathlib import Path

import numpy as np


def current_umask() -> int:
    """The process's umask: Linux says it in ``/proc/self/status``; elsewhere it is read by setting
    it and setting it back (POSIX's only way, which another thread could see for a moment)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write(path: str | os.PathLike, data: bytes | str) -> Path:
    """Write ``data`` (bytes, or text as UTF-8) to ``path`` atomically; returns the path. The
    folder must exist; the temporary file is removed if the write fails. The file's mode is what
    an ordinary new file gets (0666 less the umask: 0644 by default), not the temporary's private
    0600, so another user or a web server can read what the tool made where the umask allows."""
    path = Path(path)
    payload = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o666 & ~current_umask())
        with os.fdopen(fd, "wb") as fh:
            fh.write(payload)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def to_uint8(image: np.ndarray) -> np.ndarray:
    """An (H, W, C) image as uint8: uint8 as it is, anything else read as floats in [0, 1]
    (clipped, rounded)."""
    img = np.asarray(image)
    return img if img.dtype == np.uint8 else (np.clip(img, 0, 1) * 255).round().astype(np.uint8)


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of an (H, W, 3|4) image (:func:`to_uint8`); ``ValueError`` for other shapes."""
    from PIL import Image

    img = to_uint8(image)
    if img.ndim != 3 or img.shape[2] not in (3, 4) or not img.size:
        raise ValueError(f"image must be a non-empty (H, W, 3|4) array, got {img.shape}")
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(img)).save(buf, format="PNG")
    return buf.getvalue()
