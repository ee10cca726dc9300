"""``proctex generate`` on Ray Data: parameter rows through two ``map_batches`` stages on actor pools
(the family's model and its networks and textures load once per actor), streamed, so shape making
and texturing pipeline; the driver tallies the finished rows (progress, the failure bound) and
writes the manifest. The stages and the output layout are the core's
(:mod:`proctex.generate`): the files equal the single-process run's."""

from __future__ import annotations

import os
import time
from typing import Any, Callable

from proctex.generate import (
    GenerateSettings,
    ShapeStage,
    Tally,
    TextureStage,
    finish,
    start_run,
)


def parse_concurrency(text: str | None, cpus: int) -> tuple[int, int]:
    """``"SHAPES,TEXTURES"`` actor counts (default ``1,<cpus>``): texturing is the cost, one
    shape actor keeps several texture actors busy."""
    if not text:
        return 1, max(1, cpus)
    try:
        shapes, textures = (int(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"--concurrency must be SHAPES,TEXTURES actor counts, e.g. 1,2; got {text!r}") from None
    if not (1 <= shapes <= 1024 and 1 <= textures <= 1024):
        raise ValueError(f"--concurrency counts must be in 1..1024, got {text!r}")
    return shapes, textures


def generate_on_ray(
    settings: GenerateSettings,
    concurrency: tuple[int, int] | None = None,
    shape_cpus: float = 0.25,
    address: str | None = None,
    num_cpus: int | None = None,
    log: Callable[[str], None] = print,
    quiet: bool = False,
) -> dict[str, Any]:
    """Run ``settings`` on Ray Data (a private local Ray unless ``address`` or one is running).

    ``concurrency``: ``(shape actors, texture actors)``. ``shape_cpus``: the CPU share a shape actor
    asks for (making a shape costs a few percent of texturing it); the texture actors share the
    rest, at most one CPU each, so that all actors run at once. Returns the summary of :func:`proctex.generate.finish` plus seconds."""
    import ray

    t0 = time.perf_counter()
    out, rows, space = start_run(settings, log)  # bad settings fail before Ray starts
    started = False
    if not ray.is_initialized():
        if address:
            ray.init(address=address, log_to_driver=False)
            from .jobs import wait_for_cpus

            wait_for_cpus()  # worker nodes still joining (bounded: PROCTEX_CLUSTER_WAIT)
        else:
            from .build import start_private_ray

            start_private_ray(num_cpus=num_cpus)
        started = True
    try:
        cpus = int(ray.cluster_resources().get("CPU", 1))
        n_shapes, n_textures = concurrency or parse_concurrency(None, cpus)
        # every actor must fit at once: the texture actors share what the shape actors leave
        texture_cpus = max(0.05, min(1.0, (cpus - n_shapes * shape_cpus) / n_textures))
        ctx = ray.data.DataContext.get_current()
        ctx.enable_progress_bars = False
        ctx.verbose_stats_logs = False
        ds = ray.data.from_items(rows, override_num_blocks=max(1, min(len(rows), 4 * n_textures)))
        ds = ds.map_batches(
            ShapeStage, fn_constructor_args=(settings.family, settings.out, settings.format), batch_size=settings.batch_size, batch_format="numpy", concurrency=n_shapes, num_cpus=shape_cpus
        )
        gpu = {"num_gpus": 1.0 / n_textures} if settings.device.startswith("cuda") else {}  # the texture actors share the GPU
        ds = ds.map_batches(
            TextureStage,
            fn_constructor_args=(settings.family, settings.out, settings.format, settings.bake, settings.device, settings.textures),
            batch_size=settings.batch_size,
            batch_format="numpy",
            concurrency=n_textures,
            num_cpus=texture_cpus,
            **gpu,
        )
        tally = Tally(len(rows), settings.max_failed, quiet)
        for batch in ds.iter_batches(batch_size=None, batch_format="numpy"):
            tally.add(batch)
        summary = finish(out, tally.rows, space)
    finally:
        if started:
            ray.shutdown()
    return {**summary, "seconds": round(time.perf_counter() - t0, 3), "actors": {"shapes": n_shapes, "textures": n_textures, "texture_cpus": round(texture_cpus, 3)}, "cpus": cpus, "pid": os.getpid()}
