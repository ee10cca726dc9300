"""Mappers: what takes a part's points onto its group representative (step 3 of
:mod:`proctex.transfer.apply`): the networks, the solvers, the identity, chosen by name in one place
(:func:`proctex.transfer.methods.make_mapper`, the registry of methods)."""

from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Any, Protocol

import numpy as np

from proctex.geometry.surface import sample_surface
from proctex.transfer.assets import TemplateAssets


class Mapper(Protocol):
    """Maps points of a shape part (normalised frame) onto the template representative's normalised frame."""

    def map(self, group: int, vertices: np.ndarray, faces: np.ndarray, query: np.ndarray, seed: int = 0) -> np.ndarray: ...


class IdentityMapper:
    """Baseline: the normalised frames are taken to coincide (the nearest-point projection does the rest)."""

    def map(self, group: int, vertices: np.ndarray, faces: np.ndarray, query: np.ndarray, seed: int = 0) -> np.ndarray:
        return np.asarray(query, dtype=np.float64)


class SolverMapper:
    """Offline mapper: solves the correspondence of each part on the fly (``cage``, ``nearest`` or
    ``cpd``).

    Slow (seconds per part); used to build training pairs and as the pseudo-ground truth.
    ``last`` keeps the last :class:`proctex.correspond.dense.PartCorrespondence`.
    """

    def __init__(self, assets: TemplateAssets, method: str = "cage", n_points: int = 2000, cage: Any = None) -> None:
        if method not in ("cage", "nearest", "cpd"):
            raise ValueError(f"SolverMapper method must be cage, nearest or cpd, got {method!r}")
        self.assets, self.method, self.n_points, self.cage = assets, method, n_points, cage
        self.last = None

    def map(self, group: int, vertices: np.ndarray, faces: np.ndarray, query: np.ndarray, seed: int = 0) -> np.ndarray:
        from proctex.correspond.dense import correspond_parts, deform

        ga = self.assets.groups[group]
        res = correspond_parts(vertices, faces, ga.vertices, ga.faces, method=self.method, n_points=self.n_points, seed=seed, cage=self.cage)
        self.last = res
        # The representative is stored in its normalised frame already: centre 0, radius 1.
        return deform(res, query, np.zeros(3), 1.0)


_THREADS_LOCK = threading.Lock()
_THREADS_STATE = {"users": 0, "before": 0}


@contextmanager
def _torch_threads(n: int):
    """torch's (process-wide) thread count set to ``n`` while any caller is inside, and restored by
    the last one out: parts mapped side by side in threads never leave it changed."""
    import torch

    with _THREADS_LOCK:
        if _THREADS_STATE["users"] == 0:
            _THREADS_STATE["before"] = torch.get_num_threads()
            torch.set_num_threads(n)
        _THREADS_STATE["users"] += 1
    try:
        yield
    finally:
        with _THREADS_LOCK:
            _THREADS_STATE["users"] -= 1
            if _THREADS_STATE["users"] == 0:
                torch.set_num_threads(_THREADS_STATE["before"])


class NetworkMapper:
    """The run-time mapper: one ProcCorrNet per template group (:mod:`proctex.correspond.corrnet`).

    The network's global feature comes from ``context`` uniform surface samples of the part (seeded,
    so a shape always maps the same way); the per-point head then runs on the query points only.
    Groups without a network fall back to ``fallback`` (default: :class:`IdentityMapper`). With
    ``follow`` (default) each group is mapped by what the build chose for it from held-out pairs
    (``model.serving``, :func:`proctex.build.train.serving_choice`): its network, the box map
    (:func:`proctex.correspond.training.box_map`, no network run) or the fallback; without, the
    networks map every group they have.
    ``threads``: torch threads during prediction (restored afterwards; None leaves them alone).
    ``autocast``: :func:`proctex.correspond.corrnet.predict`'s; "auto" (default) runs the matrix products in
    bfloat16 on CPUs with native bfloat16 (measured 1.4x faster on a sofa's parts; the mapped points
    move by 2e-4 of the normalised frame on average, 1e-3 at most), float32 elsewhere.
    """

    def __init__(self, models: dict[int, Any], context: int | None = None, fallback: Mapper | None = None, threads: int | None = 1, autocast: str = "auto", follow: bool = True) -> None:
        from proctex.correspond.corrnet import AUTOCASTS

        if autocast not in AUTOCASTS + ("auto",):
            raise ValueError(f"autocast must be one of {AUTOCASTS + ('auto',)}, got {autocast!r}")
        self.autocast = autocast
        self.models, self.context = dict(models), context  # None: the context size each network was trained with
        self.fallback = fallback or IdentityMapper()
        # One part is a few thousand points: one thread does it in milliseconds, while two threads
        # on a busy 2-core machine stall at every OpenMP barrier (measured: 30 ms vs 1.1 s per shape).
        self.threads = threads
        self.follow = bool(follow)

    def serves(self, group: int) -> str:
        """What maps ``group``: "network", "box" or "identity" (the build's choice, stored with the
        network, when ``follow``; "identity" without a network: the fallback)."""
        model = self.models.get(group)
        if model is None:
            return "identity"
        choice = getattr(model, "serving", None) if self.follow else None
        return choice["serve"] if choice else "network"

    def map(self, group: int, vertices: np.ndarray, faces: np.ndarray, query: np.ndarray, seed: int = 0) -> np.ndarray:
        from proctex.correspond.corrnet import predict
        from proctex.correspond.training import box_map, part_extent

        model = self.models.get(group)
        serve = self.serves(group)
        if model is None or serve == "identity":
            return self.fallback.map(group, vertices, faces, query, seed)
        if serve == "box":  # the build found the network no better than the box map: no network run
            return box_map(query, part_extent(vertices), model.serving["template_extent"])
        ctx, _, _ = sample_surface(vertices, faces, int(self.context or model.context_points), seed=seed)
        if self.threads is None:
            return np.asarray(predict(model, ctx, query, autocast=self.autocast), dtype=np.float64)
        with _torch_threads(self.threads):
            return np.asarray(predict(model, ctx, query, autocast=self.autocast), dtype=np.float64)
