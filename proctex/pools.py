"""Worker processes for the in-process build: one torch thread each, spawned, shared by the stages
of one build (:func:`shared_pool`) or started for one piece of work (:func:`process_pool`)."""

from __future__ import annotations

from contextlib import contextmanager
from typing import Any, Iterator


def _one_thread() -> None:
    import torch

    torch.set_num_threads(1)


@contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Inside the block torch uses ``n`` threads (None: unchanged); the count before is restored."""
    if n is None:
        yield
        return
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(int(n))
    try:
        yield
    finally:
        torch.set_num_threads(before)


# The pool shared by the stages of one build (:func:`shared_pool`): its size and executor.
_SHARED: dict[str, Any] = {}


@contextmanager
def shared_pool() -> Iterator[None]:
    """Inside the block, :func:`process_pool` hands every stage the same worker processes
    (started when first needed): a worker's start (a spawned interpreter importing torch, the
    optimiser's first use importing torch._dynamo: 3-4 s) is paid once a build, not once a stage
    step. The pool is shut down on leaving the block."""
    if _SHARED.get("active"):  # nested: the outer block owns the pool
        yield
        return
    _SHARED["active"] = True
    try:
        yield
    finally:
        pool = _SHARED.pop("pool", None)
        _SHARED.clear()
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


@contextmanager
def process_pool(workers: int) -> Iterator[Any]:
    """A ``ProcessPoolExecutor`` of ``workers`` spawned processes of one torch thread each: inside
    :func:`shared_pool` the build's (replaced when another size is asked for, or dropped when the
    block raised: a worker died or the work was interrupted), else a new one shut down on exit.
    Work that keeps per-process state (the evaluation's context) keeps it in a module-level cache
    of the worker, keyed by what it was made for."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    if not _SHARED.get("active"):
        with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=_one_thread) as pool:
            yield pool
        return
    pool = _SHARED.get("pool")
    if pool is None or _SHARED.get("workers") != workers:
        if pool is not None:
            pool.shutdown(wait=True)
        pool = _SHARED["pool"] = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=_one_thread)
        _SHARED["workers"] = workers
    try:
        yield pool
    except BaseException:
        _SHARED.pop("pool", None)  # a broken or interrupted pool is not handed on
        pool.shutdown(wait=False, cancel_futures=True)
        raise
