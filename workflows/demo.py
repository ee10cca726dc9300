"""The main job (``make demo`` / ``proctex demo``): build a family on a local Ray, then sweep,
transfer, render and report it (:mod:`proctex.demo`)."""

from __future__ import annotations

from typing import Any, Callable

from proctex.demo import DemoResult, run_demo
from proctex.store.config import BuildConfig


def ray_builder(log: Callable[[str], None] = print, quiet: bool = False, address: str | None = None) -> Callable[[str, dict[str, Any]], dict[str, float]]:
    """A :data:`proctex.demo.Builder` running :func:`workflows.build.build_on_ray`."""

    def build(root: str, config: dict[str, Any]) -> dict[str, float]:
        from .build import build_on_ray

        state = build_on_ray(root, BuildConfig.from_dict(config), address=address, log=log, quiet=quiet)
        return dict(state["wall_seconds"])

    return build


def run_demo_on_ray(out: str, address: str | None = None, log: Callable[[str], None] = print, quiet: bool = False, **kwargs: Any) -> DemoResult:
    """:func:`proctex.demo.run_demo` with the build on Ray (a private local instance by default; one
    this call started is shut down at the end, one already running is left as it was)."""
    import ray

    started = not ray.is_initialized()
    try:
        return run_demo(out, builder=ray_builder(log, quiet, address), ray=True, log=log, quiet=quiet, **kwargs)
    finally:
        if started and ray.is_initialized():
            ray.shutdown()
