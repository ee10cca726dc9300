"""What the commands share: JSON output, argument parsers for group prompts and number pairs, and the
preview path check."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any


def _print_json(data: Any) -> None:
    print(json.dumps(data, indent=2))


def _group_prompts(arg: str | None) -> dict[str, str] | None:
    """``--group-prompts``: inline JSON or the path of a JSON file, ``{"group label or index": prompt}``."""
    if not arg:
        return None
    if os.path.isfile(arg):
        size = os.path.getsize(arg)
        if size > MAX_JSON_ARG:
            raise ValueError(f"--group-prompts: {arg} has {size} bytes (at most {MAX_JSON_ARG}: at most 256 prompts of 200 characters)")
        text = Path(arg).read_text(errors="replace")
    else:
        text = arg
    return json_strings(text, "--group-prompts", '{"seat": "red velvet", "2": "oak"}')


#: bytes of a JSON file a flag names (``--group-prompts``), checked before it is read
MAX_JSON_ARG = 256 * 1024


def json_strings(text: str, flag: str, example: str) -> dict[str, str]:
    """A flag's JSON object of strings (``{"3": "legs"}``), keys as strings; ``ValueError`` naming
    ``flag`` with an ``example`` otherwise."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{flag} is not valid JSON ({exc}); expected e.g. '{example}'") from exc
    if not isinstance(data, dict) or not all(isinstance(v, str) for v in data.values()):
        raise ValueError(f"{flag} must be a JSON object of strings, e.g. {example}")
    return {str(k): v for k, v in data.items()}


def _check_preview_path(preview: str | None) -> None:
    """``--preview`` must name a .png file (checked before any work)."""
    if preview is not None and Path(preview).suffix.lower() != ".png":
        raise ValueError(f"--preview must name a .png file, got {preview!r}")


def _pair(text: str | None, what: str, n: int = 2) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError as exc:
        raise ValueError(f"{what} must be numbers separated by commas, got {text!r}") from exc
    if len(vals) == 1 and n == 2:
        vals = vals * 2
    if len(vals) != n:
        raise ValueError(f"{what} needs {n} numbers, got {text!r}")
    return vals


def check_output_file(path: str | None, force: bool, what: str = "--out") -> None:
    """Refuse an output file path before any work: a folder, a parent that is a file or not
    writable, or (without ``--force``) an existing file. ``None`` passes."""
    if path is None:
        return
    p = Path(path)
    if p.is_dir():
        raise ValueError(f"{what} {path!r} is a folder; name a file")
    if p.exists() and not force:
        raise ValueError(f"{what} {path!r} exists; pass --force to overwrite it")
    parent = p.parent if str(p.parent) else Path(".")
    probe = parent
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise ValueError(f"{what} {path!r}: {probe} is not a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise ValueError(f"{what} {path!r}: cannot write in {probe}")


def finite(name: str, value: float, lo: float | None = None, hi: float | None = None) -> float:
    """``value`` if finite and within [lo, hi]; else a ``ValueError`` naming the flag."""
    if not math.isfinite(value) or (lo is not None and value < lo) or (hi is not None and value > hi):
        bounds = f" in [{lo:g}, {hi:g}]" if lo is not None and hi is not None else (f" >= {lo:g}" if lo is not None else "")
        raise ValueError(f"{name} must be a finite number{bounds}, got {value!r}")
    return value
