"""What the commands share: JSON output, argument parsers for group prompts and number pairs, and the
preview path check."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any


def _print_json(data: Any) -> None:
    print(json.dumps(data, indent=2))


def _group_prompts(arg: str | None) -> dict[str, str] | None:
    """``--group-prompts``: inline JSON or the path of a JSON file, ``{"group label or index": prompt}``."""
    if not arg:
        return None
    text = Path(arg).read_text() if os.path.isfile(arg) else arg
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"--group-prompts is not valid JSON ({exc}); expected e.g. '{{\"seat\": \"red velvet\"}}'") from exc
    if not isinstance(data, dict) or not all(isinstance(v, str) for v in data.values()):
        raise ValueError('--group-prompts must be a JSON object of strings, e.g. {"seat": "red velvet", "2": "oak"}')
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
