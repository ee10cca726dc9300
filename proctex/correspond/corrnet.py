"""ProcCorrNet: one small network per template part group that predicts dense correspondence.

The offline cage solver (:mod:`proctex.correspond`) maps surface samples of a shape's part onto the
template part. ProcCorrNet learns that map over the family, so that at run time a new shape's part is
mapped in one forward pass.

Frames (docs/correspondence.md): inputs are points of the shape's part in *that part's* normalised frame (centre =
bounding-box centre, divided by the L∞ radius; :func:`proctex.geometry.surface.normalised_frame`), outputs are
points in the *template part's* normalised frame. Both lie in [-1, 1]³, which is the only input
normalisation the network needs (the checkpoint records it as ``extra["frame"]``).

Architecture (the paper's):

- local encoder: 4 linear layers ``3 -> 128 -> 128 -> 128 -> 256``, ReLU after each, per point;
- global feature: max-pool of the local features over a *context* set of points of the part (256-d);
- decoder: per query point ``[local (256) | global (256)]`` (512-d) through 4 linear layers
  ``512 -> 256 -> 256 -> 256 -> 3``, ReLU between them, none at the end;
- one addition, on by default (``CorrNetConfig.residual``): the decoder's output is added to the
  query point, i.e. the network predicts the displacement from the shape's normalised frame to the
  template's. Both frames are normalised, so the map is close to the identity (cage targets lie
  0.015-0.08 from their sources on the sofa and chair) and learning the displacement is easier:
  measured on the chair, pseudo-ground-truth error -10 to -40 % per group, ground-truth error up to
  -45 %, same cost;
- a second, also on by default (``CorrNetConfig.frame = "box"``): each input axis is divided by the
  part's half extent (read from the context) and the output multiplied by the template part's half
  extents (a buffer set from the training targets, saved with the weights), so the zero residual is
  the map of one bounding box onto the other, the change most procedural parameters make (on the
  mug: tracked-point variance 0.137 -> 0.081, GT error 0.036 -> 0.021; docs/fidelity-history.md).

Because the global feature is a function of the point *set*, it is computed once from a fixed-size
context (``CorrNetConfig.context_points`` surface samples of the part; fewer points are topped up by
repetition, which leaves a max-pool unchanged) and queries of any number are decoded against it
(:func:`encode`, :func:`decode`, :func:`predict`). The decoder's first layer is applied as
``W_local @ local + (W_global @ global + b)`` with the global half computed once per shape (same
result as the concatenation, :func:`proctex._reference.corrnet.decode_reference`, at about half the cost).

Training (:func:`proctex.correspond.training.train`): Adam on random batches of pairs; each step draws ``shapes_per_batch``
pairs, for each a context of ``context_points`` samples and ``query_points`` query samples, and
minimises the loss between the predicted and the cage points at the queries. Validation pairs
(held-out shapes) drive early stopping; the best validation state is kept. Errors are reported as
Euclidean distances in the template part's normalised frame (:func:`eval_step`).

Persistence (:func:`save`, :func:`load`): ``torch.save`` of plain types and tensors only, written
atomically, loaded with ``torch.load(weights_only=True)``.
"""

from __future__ import annotations

import math
import os
import pickle
import weakref
from dataclasses import asdict, dataclass, fields
from functools import lru_cache
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F
from proctex.torch_kernels import resolve_vml

resolve_vml()  # MKL's kernels chosen on one thread (see proctex.torch_kernels)

FORMAT = "proctex.corrnet/1"  # the checkpoint format name (kept from before the subpackages: old files load)
LOSSES = ("mse", "l2")
SCHEDULES = ("constant", "cosine", "step")
QUERY_MODES = ("context", "separate")
FRAMES = ("uniform", "box")
#: Smallest half extent of a box frame axis (normalised units): flat parts keep their thin axis.
MIN_EXTENT = 0.05
AUTOCASTS = ("none", "bfloat16")
#: :func:`predict` decodes queries in row counts rounded up to a multiple of this (the extra rows
#: zeros, dropped after): oneDNN, behind torch's CPU matrix products, makes a kernel for each new
#: shape, which costs several times the product itself for a part's few hundred points (measured on
#: the demo sofa's arms: 16.8 ms a call over sizes never seen, 3.5 ms rounded); each row's result
#: does not depend on the other rows.
QUERY_BUCKET = 64
DTYPES = {"float32": torch.float32, "float64": torch.float64}
#: A pair needs at least this many points to describe a part's surface.
MIN_PAIR_POINTS = 16
#: Pair coordinates beyond this magnitude cannot be in a normalised frame ([-1, 1]³).
FRAME_LIMIT = 1.5

Pair = tuple[np.ndarray, np.ndarray]
#: Whether a build trains several groups' networks in one batched loop (:attr:`CorrNetConfig.together`).
TOGETHER = ("auto", "on", "off")
#: How training points are weighted by the teacher's confidence (:attr:`CorrNetConfig.confidence`).
CONFIDENCES = ("none", "neighbours")


# ------------------------------------------------------------------------------------------- config
@dataclass
class CorrNetConfig:
    """Every setting of the network and its training.

    Attributes:
        context_points: N, points the global feature is max-pooled over (training and prediction).
        query_points: points per shape per step at which the loss is taken; with
            ``query_mode="context"`` the queries are the first ``query_points`` context points
            (``query_points <= context_points``), with ``"separate"`` an independent sample of the
            same shape.
        query_mode: "context" or "separate" (see ``query_points``).
        shapes_per_batch: pairs (shapes) per step.
        iterations: maximum optimisation steps.
        lr: Adam learning rate; schedule: "constant", "cosine" (to ``lr * lr_final`` at
            ``iterations``) or "step" (times 0.1 at 60 % and 85 % of ``iterations``);
            lr_final: the cosine schedule's final factor.
        weight_decay: Adam's L2 weight decay.
        loss: "mse" (mean squared distance) or "l2" (mean Euclidean distance).
        eval_every: steps between validation evaluations; patience: evaluations without a
            validation improvement (relative ``min_delta``) before stopping (0 = never stop early);
            ``min_iterations``: no early stop before this many steps (the first evaluations of a
            network started at the box map are noise around it).
        local_hidden, feature_dim, decoder_hidden: layer widths (the paper: 128, 256, 256).
        residual: predict the displacement (output = query + decoder), see the module docstring.
        frame: "uniform" (points in the parts' normalised frames, as the paper) or "box" (each
            axis divided by the part's half extent, read from the context, and the output
            multiplied by the template part's half extents: with ``residual`` the zero
            displacement is then the map of one bounding box onto the other, the map most
            procedural parameter changes make).
        zero_init: with ``residual``, the decoder's last layer starts at zero, so an untrained
            network is the map the frame gives for free (the box map in the box frame) and
            training starts from it rather than from a random displacement; :func:`train`
            evaluates that start too, so early stopping can keep it. Off by default: on the real
            chair, groups whose randomly initialised networks beat the box map ended at the
            start (held-out 0.0272 vs 0.0176 on one group, with or without ``min_iterations``
            1000; docs/results.md, "Tried, not defaults").
        confidence: how each training point's loss is weighted by the teacher's confidence:
            "none" (all alike) or "neighbours" (:mod:`proctex.correspond.confidence`: by how well
            the pair's targets agree with those of the ``confidence_neighbours`` most similar
            training shapes, ``1 / (1 + (d / s)^2)`` with ``s`` = ``confidence_scale`` times the
            group's median disagreement). Validation stays unweighted (the held-out error is
            the pseudo-ground truth the paper reports). Off by default: the weights point at the
            teacher's errors on the fork, chair and sofa, but a fork trained with them ended no
            better against the truth (GT mean 0.0068 -> 0.0074; docs/results.md, "Tried, not defaults").
        together: whether a build trains a worker's groups in one batched loop
            (:func:`proctex.correspond.grouped.train_together`: each keeps its own network, batches,
            early stopping and best state): "on", "off", or "auto" (on a GPU, where batched products
            pay; off on CPUs, where one group after another in worker processes of one thread each
            costs the same per step, 20.6 vs 22.7 ms on the demo's sofa, and a pool hands out groups
            as workers free up: ``tests/bench/bench_train_together.py``).
        plain_below: a group whose plain map (the box map or the identity, the better) lies within
            this mean distance of its held-out cage points (normalised frame) is not trained: its
            network stays at the frame's own map (the zero residual) and the serving choice picks
            the plain map, as it did on every such group measured (the demo, the sofa export, the
            Blender chair, cabinet and table: groups at 0 to 4.6e-4 all served the plain map after
            training; the closest that a network won sat at 2.4e-3). The pairs stage decides it
            first, on each group's held-out and as many probe train shapes, and skips the other
            train pairs of such a group (the demo: 18 of 78 pairs, the sofa export 68 of 400).
            0 trains every group and solves every pair. Needs ``residual`` (without it nothing is
            skipped).
        seed: weights, batch sampling and evaluation contexts.
        device: "cpu", "cuda", "cuda:<i>" or "auto" (CUDA when present); dtype: "float32" or "float64".
        autocast: "auto" (bfloat16 where the CPU has it natively, AVX512-BF16 or AMX, float32
            elsewhere and on GPUs: :func:`resolve_autocast`), "none" or "bfloat16" (matrix products
            in bfloat16, the loss in float32). On 2 AVX512-BF16 cores bfloat16 trains 1.57x faster
            on the demo's sofa and 1.88x on the real sofa export with the same errors (ground truth
            0.01102 -> 0.01098 and 0.004504 -> 0.004500; ``tests/bench/bench_train_pool.py
            --autocast``); emulated bfloat16 is slow, hence "auto".

    Defaults were chosen by measurement on CPU (``tests/bench/bench_corrnet.py`` on the real sofa
    data, chair, mug and table; one thread). Accuracy was flat (sofa pseudo-ground-truth error
    within +-0.0006 per group) over lr 3e-4..3e-3, context 256..1024, queries 128..512, 4..16 shapes
    per batch, MSE or Euclidean loss, and queries drawn from the context or separately, so the
    cheapest setting on that plateau was kept (context 512 rather than 256: better ground truth
    on one chair group). 800 iterations under-train one sofa group and 1000 the mug; 3000 with
    early stopping reach the plateau (the mug still gains slightly up to 4000).
    """

    context_points: int = 512
    query_points: int = 256
    query_mode: str = "context"
    shapes_per_batch: int = 4
    iterations: int = 3000
    lr: float = 1e-3
    schedule: str = "cosine"
    lr_final: float = 0.05
    weight_decay: float = 0.0
    loss: str = "mse"
    eval_every: int = 100
    patience: int = 10
    min_delta: float = 1e-3
    min_iterations: int = 0
    local_hidden: int = 128
    feature_dim: int = 256
    decoder_hidden: int = 256
    residual: bool = True
    frame: str = "box"
    zero_init: bool = False
    confidence: str = "none"
    confidence_neighbours: int = 3
    confidence_scale: float = 1.0
    together: str = "auto"
    plain_below: float = 5e-4
    seed: int = 0
    device: str = "cpu"
    dtype: str = "float32"
    autocast: str = "auto"

    def validate(self) -> "CorrNetConfig":
        """Raise ``ValueError`` naming the first bad setting; returns ``self``."""
        positive = ("context_points", "query_points", "shapes_per_batch", "iterations", "eval_every", "local_hidden", "feature_dim", "decoder_hidden")
        for name in positive:
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
                raise ValueError(f"CorrNetConfig.{name} must be a positive integer, got {v!r}")
        if self.together not in TOGETHER:
            raise ValueError(f"CorrNetConfig.together must be one of {TOGETHER}, got {self.together!r}")
        if self.confidence not in CONFIDENCES:
            raise ValueError(f"CorrNetConfig.confidence must be one of {CONFIDENCES}, got {self.confidence!r}")
        v = self.confidence_neighbours
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
            raise ValueError(f"CorrNetConfig.confidence_neighbours must be a positive integer, got {v!r}")
        v = self.confidence_scale
        if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"CorrNetConfig.confidence_scale must be a positive number, got {v!r}")
        for name in ("patience", "seed", "min_iterations"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 0:
                raise ValueError(f"CorrNetConfig.{name} must be a non-negative integer, got {v!r}")
        if not (isinstance(self.lr, (int, float)) and math.isfinite(self.lr) and self.lr > 0):
            raise ValueError(f"CorrNetConfig.lr must be a positive number, got {self.lr!r}")
        if not (isinstance(self.lr_final, (int, float)) and 0 <= self.lr_final <= 1):
            raise ValueError(f"CorrNetConfig.lr_final must be in [0, 1], got {self.lr_final!r}")
        for name in ("weight_decay", "min_delta", "plain_below"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"CorrNetConfig.{name} must be a finite number >= 0, got {v!r}")
        if self.query_mode not in QUERY_MODES:
            raise ValueError(f"CorrNetConfig.query_mode must be one of {QUERY_MODES}, got {self.query_mode!r}")
        if self.query_mode == "context" and self.query_points > self.context_points:
            raise ValueError(f"query_mode 'context' needs query_points <= context_points, got {self.query_points} > {self.context_points}")
        if self.schedule not in SCHEDULES:
            raise ValueError(f"CorrNetConfig.schedule must be one of {SCHEDULES}, got {self.schedule!r}")
        if self.loss not in LOSSES:
            raise ValueError(f"CorrNetConfig.loss must be one of {LOSSES}, got {self.loss!r}")
        if self.dtype not in DTYPES:
            raise ValueError(f"CorrNetConfig.dtype must be one of {tuple(DTYPES)}, got {self.dtype!r}")
        if self.autocast not in AUTOCASTS + ("auto",):
            raise ValueError(f"CorrNetConfig.autocast must be one of {AUTOCASTS + ('auto',)}, got {self.autocast!r}")
        if self.autocast == "bfloat16" and self.dtype != "float32":
            raise ValueError(f"autocast {self.autocast!r} needs dtype 'float32', got {self.dtype!r}")
        if self.frame not in FRAMES:
            raise ValueError(f"CorrNetConfig.frame must be one of {FRAMES}, got {self.frame!r}")
        if not isinstance(self.residual, bool):
            raise ValueError(f"CorrNetConfig.residual must be a bool, got {self.residual!r}")
        resolve_device(self.device)
        return self

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict[str, Any]) -> "CorrNetConfig":
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError``."""
        known = {f.name for f in fields(CorrNetConfig)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown CorrNetConfig settings {unknown}; known: {sorted(known)}")
        return CorrNetConfig(**d).validate()


def resolve_device(device: str) -> torch.device:
    """``torch.device`` of a config's device string; ``ValueError`` when unknown or unavailable."""
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as e:
        raise ValueError(f"device must be 'cpu', 'cuda', 'cuda:<i>' or 'auto', got {device!r}") from e
    if dev.type not in ("cpu", "cuda"):
        raise ValueError(f"device must be 'cpu', 'cuda', 'cuda:<i>' or 'auto', got {device!r}")
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {device!r} requested but CUDA is not available (use 'cpu' or 'auto')")
    return dev


# -------------------------------------------------------------------------------------------- model
def _mlp(widths: Sequence[int], last_relu: bool) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(widths) - 1):
        layers.append(nn.Linear(widths[i], widths[i + 1]))
        if i < len(widths) - 2 or last_relu:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class ProcCorrNet(nn.Module):
    """The paper's network (see the module docstring). Points are the last-but-one axis.

    Args:
        local_hidden, feature_dim, decoder_hidden: widths (128, 256, 256 in the paper).
        context_points: N, the context size the network was trained with (used by :func:`predict`).
        residual: output = query + decoder; frame: "uniform" or "box" (:class:`CorrNetConfig`).
    """

    def __init__(self, local_hidden: int = 128, feature_dim: int = 256, decoder_hidden: int = 256, context_points: int = 512, residual: bool = True, frame: str = "uniform") -> None:
        super().__init__()
        if frame not in FRAMES:
            raise ValueError(f"frame must be one of {FRAMES}, got {frame!r}")
        self.feature_dim = int(feature_dim)
        self.context_points = int(context_points)
        self.residual = bool(residual)
        self.frame = frame
        self.local = _mlp([3, local_hidden, local_hidden, local_hidden, feature_dim], last_relu=True)
        self.decoder = _mlp([2 * feature_dim, decoder_hidden, decoder_hidden, decoder_hidden, 3], last_relu=False)
        # The template part's half extents (box frame; set by :func:`train` from the targets).
        self.register_buffer("template_extent", torch.ones(3), persistent=frame == "box")

    def extent(self, context: torch.Tensor) -> torch.Tensor:
        """Half extents ``(B, 1, 3)`` of a context ``(B, N, 3)`` in its normalised frame (box frame;
        at least :data:`MIN_EXTENT`)."""
        return context.detach().abs().amax(dim=1, keepdim=True).clamp_min(MIN_EXTENT)

    def encode(self, context: torch.Tensor) -> torch.Tensor:
        """``context (B, N, 3)`` -> global feature ``(B, feature_dim)`` (max over the N points); in
        the box frame ``(B, feature_dim + 3)``: the pooled feature, then the context's half extents."""
        if self.frame == "box":
            e = self.extent(context)
            return torch.cat([self.local(context / e).amax(dim=1), e[:, 0]], dim=-1)
        return self.local(context).amax(dim=1)

    def head(self, local: torch.Tensor, global_feature: torch.Tensor, query: torch.Tensor) -> torch.Tensor:
        """Decoder on precomputed ``local (B, Q, F)`` features of ``query (B, Q, 3)`` (box frame:
        already divided by the extents) against the pooled ``global (B, F)`` -> ``(B, Q, 3)``. The
        first layer is split: the global half once per shape."""
        first: nn.Linear = self.decoder[0]  # type: ignore[assignment]
        F_ = self.feature_dim
        h = F.linear(local, first.weight[:, :F_]) + F.linear(global_feature, first.weight[:, F_:], first.bias)[:, None, :]
        out = self.decoder[1:](h)
        out = out + query if self.residual else out
        return out * self.template_extent if self.frame == "box" else out

    def _split(self, query: torch.Tensor, global_feature: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if self.frame == "box":
            return query / global_feature[:, None, self.feature_dim :], global_feature[:, : self.feature_dim]
        return query, global_feature

    def decode(self, query: torch.Tensor, global_feature: torch.Tensor) -> torch.Tensor:
        """``query (B, Q, 3)`` against ``global`` (from :meth:`encode`) -> template points ``(B, Q, 3)``."""
        q, g = self._split(query, global_feature)
        return self.head(self.local(q), g, q)

    def forward(self, points: torch.Tensor, n_query: int | None = None) -> torch.Tensor:
        """``points (B, N, 3)`` are the context; returns ``(B, Q, 3)`` for the first ``Q = n_query``
        (default N) of them, sharing their local features with the encoder."""
        if self.frame == "box":
            points = points / self.extent(points)
        local = self.local(points)
        q = points.shape[1] if n_query is None else int(n_query)
        return self.head(local[:, :q], local.amax(dim=1), points[:, :q])


def zero_residual(model: ProcCorrNet) -> None:
    """Zero the decoder's last layer: a residual network then maps every point by its frame's own
    map (the box map in the box frame), whatever its other weights."""
    last = model.decoder[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()


def build_model(config: CorrNetConfig) -> ProcCorrNet:
    """A freshly initialised network (seeded by ``config.seed``) on the config's device and dtype."""
    config.validate()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        model = ProcCorrNet(config.local_hidden, config.feature_dim, config.decoder_hidden, config.context_points, config.residual, config.frame)
        if config.zero_init and config.residual:
            zero_residual(model)
    return model.to(device=resolve_device(config.device), dtype=DTYPES[config.dtype])


def _model_spec(model: ProcCorrNet) -> tuple[torch.device, torch.dtype]:
    p = next(model.parameters())
    return p.device, p.dtype


# ------------------------------------------------------------------------------------- validation
def check_points(points: Any, what: str, min_points: int = 1) -> np.ndarray:
    """``points`` as a finite ``(n, 3)`` float64 array with ``n >= min_points``, else ``ValueError``."""
    try:
        a = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what}: expected an (n, 3) array of numbers") from e
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{what}: expected shape (n, 3), got {a.shape}")
    if len(a) < min_points:
        raise ValueError(f"{what}: expected at least {min_points} points, got {len(a)}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: contains NaN or inf")
    return a


def check_pairs(pairs: Any, what: str, allow_empty: bool = False) -> list[tuple[np.ndarray, np.ndarray]]:
    """Validate a sequence of ``(src (n, 3), dst (n, 3))`` pairs in normalised frames.

    Returns float32 copies. Raises ``ValueError`` on a wrong structure or shape, mismatched n,
    ``n < MIN_PAIR_POINTS``, NaN/inf, or coordinates beyond ``FRAME_LIMIT`` (not a normalised frame).
    """
    if pairs is None or isinstance(pairs, (str, bytes, np.ndarray)):
        raise ValueError(f"{what}: expected a sequence of (src, dst) pairs, got {type(pairs).__name__}")
    pairs = list(pairs)
    if not pairs and not allow_empty:
        raise ValueError(f"{what}: no pairs")
    out = []
    for i, p in enumerate(pairs):
        if not isinstance(p, (tuple, list)) or len(p) != 2:
            raise ValueError(f"{what}[{i}]: expected a (src, dst) pair, got {type(p).__name__}")
        src = check_points(p[0], f"{what}[{i}] src", MIN_PAIR_POINTS)
        dst = check_points(p[1], f"{what}[{i}] dst", MIN_PAIR_POINTS)
        if src.shape != dst.shape:
            raise ValueError(f"{what}[{i}]: src and dst must have the same shape, got {src.shape} and {dst.shape}")
        lim = max(np.abs(src).max(), np.abs(dst).max())
        if lim > FRAME_LIMIT:
            raise ValueError(f"{what}[{i}]: coordinates up to {lim:.3g}; pairs must be in normalised part frames ([-1, 1]^3)")
        out.append((src.astype(np.float32), dst.astype(np.float32)))
    return out


# ---------------------------------------------------------------------------------- train and eval
#: oneDNN ISA limits (``ONEDNN_MAX_CPU_ISA``) under which bfloat16 products are still native.
_ONEDNN_BF16_ISAS = (
    "AVX512_CORE_BF16",
    "AVX512_CORE_FP16",
    "AVX512_CORE_AMX",
    "AVX512_CORE_AMX_FP16",
    "AVX10_1_512",
    "AVX10_1_512_AMX",
    "AVX10_1_512_AMX_FP16",
    "AVX10_2_512",
    "AVX10_2_512_AMX_2",
    "ALL",
    "DEFAULT",
    "",
)


def native_bfloat16(device: torch.device | str = "cpu") -> bool:
    """Whether ``device`` runs bfloat16 matrix products natively (CPUs with AVX512-BF16 or AMX;
    CUDA devices reporting bfloat16 support), so autocast there is faster rather than emulated.

    On a CPU this honours torch's own dispatch limits, so a machine told to behave like one without
    AVX-512 (``ATEN_CPU_CAPABILITY=avx2``, or ``ONEDNN_MAX_CPU_ISA`` below ``AVX512_CORE_BF16``)
    takes the float32 path that such a machine takes (the suite runs that way too:
    tests/test_portability.py)."""
    device = torch.device(device)
    try:
        if device.type == "cpu":
            if not torch.backends.cpu.get_cpu_capability().upper().startswith("AVX512"):
                return False
            isa = os.environ.get("ONEDNN_MAX_CPU_ISA", os.environ.get("DNNL_MAX_CPU_ISA", "")).strip().upper()
            if isa not in _ONEDNN_BF16_ISAS:
                return False
            return bool(torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported())
        if device.type == "cuda":
            return bool(torch.cuda.is_bf16_supported())
    except (AttributeError, RuntimeError):  # a torch without the probe: assume not
        return False
    return False


def trains_together(config: CorrNetConfig, groups: int) -> bool:
    """Whether ``groups`` networks with ``config`` are trained in one batched loop
    (:attr:`CorrNetConfig.together`; only with ``query_mode`` "context")."""
    if groups < 2 or config.query_mode != "context" or config.together == "off":
        return False
    return config.together == "on" or resolve_device(config.device).type == "cuda"


def resolve_autocast(mode: str, device: torch.device | str = "cpu") -> str:
    """``mode`` of :func:`predict` as one of :data:`AUTOCASTS`: ``"auto"`` is ``"bfloat16"`` on a
    CPU with native bfloat16 (:func:`native_bfloat16`; there the networks are most of a transfer's
    time), else ``"none"`` (GPUs run float32 well inside the budget)."""
    if mode == "auto":
        device = torch.device(device)
        return "bfloat16" if device.type == "cpu" and native_bfloat16(device) else "none"
    if mode not in AUTOCASTS:
        raise ValueError(f"autocast must be one of {AUTOCASTS + ('auto',)}, got {mode!r}")
    return mode


def _autocast(device: torch.device, mode: str) -> torch.autocast:
    """bfloat16 autocast context on ``device`` when ``mode == "bfloat16"`` (disabled otherwise)."""
    if mode not in AUTOCASTS:
        raise ValueError(f"autocast must be one of {AUTOCASTS}, got {mode!r}")
    return torch.autocast(device_type=device.type, dtype=torch.bfloat16, enabled=mode == "bfloat16")


# ---------------------------------------------------------------------------------------- predict
def encode(model: ProcCorrNet, context: torch.Tensor) -> torch.Tensor:
    """``context (B, N, 3)`` -> global feature ``(B, F)`` (no gradient tracking is changed)."""
    return model.encode(context)


def decode(model: ProcCorrNet, query: torch.Tensor, global_feature: torch.Tensor) -> torch.Tensor:
    """``query (B, Q, 3)`` against ``global (B, F)`` -> ``(B, Q, 3)``."""
    return model.decode(query, global_feature)


def predict(
    model: ProcCorrNet,
    context_points: np.ndarray,
    query_points: np.ndarray,
    chunk: int = 8192,
    seed: int = 0,
    autocast: str = "none",
) -> np.ndarray:
    """Template points for ``query_points`` of one part: the modules' ``decode(query,
    encode(context))``, computed with the weights as :func:`_inference_weights` keeps them (cast to
    bfloat16 once under ``autocast``, as autocast would in every call) and the context and the
    first chunk of queries through the point MLP in one pass.

    Args:
        context_points: (N', 3) surface samples of the part (its normalised frame); resampled to the
            model's ``context_points`` (seeded by ``seed``; without replacement when N' is larger,
            every point plus repeats when smaller).
        query_points: (Q, 3) points of the same part (same frame), e.g. samples plus mesh vertices.
        chunk: queries decoded per forward pass (memory bound; the result does not depend on it),
            each rounded up to a multiple of :data:`QUERY_BUCKET` rows.
        autocast: "bfloat16" runs the matrix products in bfloat16 (float32 models only): on CPUs
            with AMX / AVX512-BF16 about 2x to 5x faster, at a cost of ~1e-3 at most in the output
            with ``residual`` networks; slower on CPUs without native bfloat16. "auto": bfloat16
            for float32 models on devices with native bfloat16 (:func:`resolve_autocast`), else none.

    Returns:
        (Q, 3) float64 points in the template part's normalised frame.
    """
    ctx = check_points(context_points, "context points")
    qry = check_points(query_points, "query points")
    if not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"chunk must be a positive integer, got {chunk!r}")
    if len(ctx) != model.context_points:
        ctx = ctx[sample_indices(len(ctx), model.context_points, np.random.default_rng(seed))]
    device, dtype = _model_spec(model)
    if autocast == "auto":
        autocast = resolve_autocast(autocast, device) if dtype == torch.float32 else "none"
    _resolve_autocast_for(autocast, dtype)
    out = np.empty((len(qry), 3))
    with torch.inference_mode():
        w = _inference_weights(model, autocast)
        c = torch.as_tensor(ctx, device=device, dtype=dtype)
        scale = c.abs().amax(dim=0, keepdim=True).clamp_min(MIN_EXTENT) if model.frame == "box" else None
        c = c / scale if scale is not None else c
        for s in range(0, len(qry), chunk):
            rows = qry[s : s + chunk]
            n = len(rows)
            padded = np.zeros((-(-n // QUERY_BUCKET) * QUERY_BUCKET, 3), dtype=rows.dtype)
            padded[:n] = rows
            q = torch.as_tensor(padded, device=device, dtype=dtype)
            q = q / scale if scale is not None else q
            if s == 0:  # the context and the first chunk through the shared point MLP in one pass
                both = _mlp_rows(torch.cat([c, q]), w.local, last_relu=True, fused=w.fused)
                g, local = both[: len(c)].amax(dim=0, keepdim=True), both[len(c) :]
                g_part = F.linear(g, w.first_global, w.first_bias)  # g, local: already in the weights' dtype
            else:
                local = _mlp_rows(q, w.local, last_relu=True, fused=w.fused)
            h = F.linear(local, w.first_local)
            h.add_(g_part).relu_()  # in place: the same bits as a new tensor each, without its allocation
            y = _mlp_rows(h, w.decoder, last_relu=False, fused=w.fused)
            y = y + q if model.residual else y
            y = y * model.template_extent if model.frame == "box" else y
            out[s : s + n] = y[:n].to("cpu", torch.float64).numpy()
    return out


def _resolve_autocast_for(autocast: str, dtype: torch.dtype) -> None:
    """``ValueError`` unless ``autocast`` (resolved) suits a model of ``dtype``."""
    if autocast not in AUTOCASTS:
        raise ValueError(f"autocast must be one of {AUTOCASTS}, got {autocast!r}")
    if autocast != "none" and dtype != torch.float32:
        raise ValueError(f"autocast {autocast!r} needs a float32 model, got {dtype}")


@dataclass(frozen=True)
class _Weights:
    """A network's weights as :func:`predict` multiplies with them: in bfloat16, cast once, where it
    runs under bfloat16 autocast (autocast casts every weight again in every call), else the
    parameters themselves. ``local``/``decoder``: ``[(weight, bias)]`` of the point MLP and of the
    decoder after its first layer; the first layer split into its local and global halves.
    ``fused``: their layers run as oneDNN's linear with its ReLU in the same pass
    (:func:`_fused_linear`), which :func:`_fuses_exactly` found to give the plain layers' bits."""

    key: tuple
    local: list[tuple[torch.Tensor, torch.Tensor]]
    first_local: torch.Tensor
    first_global: torch.Tensor
    first_bias: torch.Tensor
    decoder: list[tuple[torch.Tensor, torch.Tensor]]
    fused: bool = False


_WEIGHTS: "weakref.WeakKeyDictionary[ProcCorrNet, _Weights]" = weakref.WeakKeyDictionary()


def _inference_weights(model: ProcCorrNet, autocast: str) -> _Weights:
    """The :class:`_Weights` of ``model`` for ``autocast``, made again only when a parameter changed
    (each tensor's in-place version counter and storage are the key: training between predictions
    moves them)."""
    params = list(model.parameters())
    key = (autocast, tuple((p.data_ptr(), p._version) for p in params))
    have = _WEIGHTS.get(model)
    if have is not None and have.key == key:
        return have
    compute = torch.bfloat16 if autocast == "bfloat16" else None

    def cast(t: torch.Tensor) -> torch.Tensor:
        t = t.detach()
        return t.to(compute).contiguous() if compute is not None else t

    def pairs(seq: nn.Sequential) -> list[tuple[torch.Tensor, torch.Tensor]]:
        return [(cast(m.weight), cast(m.bias)) for m in seq if isinstance(m, nn.Linear)]

    first: nn.Linear = model.decoder[0]  # type: ignore[assignment]
    F_ = model.feature_dim
    local, decoder = pairs(model.local), pairs(model.decoder)[1:]
    fused = compute is not None and params[0].device.type == "cpu" and _fuses_exactly(local + decoder)
    made = _Weights(key, local, cast(first.weight[:, :F_]), cast(first.weight[:, F_:]), cast(first.bias), decoder, fused)
    _WEIGHTS[model] = made
    return made


@lru_cache(maxsize=1)
def _fused_linear() -> Any:
    """oneDNN's linear layer with its activation applied in the same pass over the output
    (``torch.ops.mkldnn._linear_pointwise``, what torch's compiler emits for ``relu(linear(x))`` on
    CPUs), or None where this torch has no oneDNN or no such operator. In bfloat16 it saves the
    ReLU's own pass over every layer's output: a ProcCorrNet prediction of 1,000-3,000 points took
    1.5-1.9x less time on 2 AMX cores (the demo family's network)."""
    if not torch.backends.mkldnn.is_available():
        return None
    try:
        return torch.ops.mkldnn._linear_pointwise
    except (AttributeError, RuntimeError):
        return None


def _fuses_exactly(layers: list[tuple[torch.Tensor, torch.Tensor]]) -> bool:
    """Whether :func:`_fused_linear` runs bfloat16 CPU layers of these ``layers``' shapes and gives,
    on probes of :data:`QUERY_BUCKET` and of 16 times as many rows through each (:func:`_fuses_shapes`,
    once per process for each set of shapes), the same bits as ``F.linear`` and then ``torch.relu``:
    a ReLU applied to the rounded output is the rounded ReLU, so where both take oneDNN's product
    the answers are equal (measured on AMX cores: equal on every row of the demo family's
    predictions). A CPU or build where they differ, or where the fused operator refuses bfloat16
    (oneDNN held below AVX-512), keeps the plain layers."""
    op = _fused_linear()
    if op is None or not native_bfloat16("cpu"):
        return False
    if any(w.dtype != torch.bfloat16 or w.device.type != "cpu" or b is None or b.shape != w.shape[:1] for w, b in layers):
        return False
    return _fuses_shapes(op, tuple(tuple(w.shape) for w, _ in layers))


@lru_cache(maxsize=64)
def _fuses_shapes(op: Any, shapes: tuple[tuple[int, int], ...]) -> bool:
    """:func:`_fuses_exactly` for bfloat16 layers of weight ``shapes``, probed once per process
    with seeded random weights (which kernel oneDNN runs, and so the bits, follows the shapes and
    the CPU, not the values): a network made again after training steps, or another network of
    the same shapes, does not probe again."""
    gen = torch.Generator().manual_seed(0)
    try:
        with torch.inference_mode():
            for out, inp in shapes:
                weight = torch.randn(out, inp, generator=gen).to(torch.bfloat16)
                bias = torch.randn(out, generator=gen).to(torch.bfloat16)
                for rows in (QUERY_BUCKET, 16 * QUERY_BUCKET):  # oneDNN may choose its kernel by the row count
                    x = torch.randn(rows, inp, generator=gen).to(torch.bfloat16)
                    plain = F.linear(x, weight, bias)
                    if not (torch.equal(op(x, weight, bias, "none", [], ""), plain) and torch.equal(op(x, weight, bias, "relu", [], ""), torch.relu(plain))):
                        return False
    except RuntimeError:
        return False
    return True


def _mlp_rows(x: torch.Tensor, layers: list[tuple[torch.Tensor, torch.Tensor]], last_relu: bool, fused: bool = False) -> torch.Tensor:
    """Linear layers with ReLU between them (and after the last with ``last_relu``) on rows ``x (r,
    d)``; ``fused``: each layer and its ReLU in one oneDNN pass (:func:`_fused_linear`; the same bits)."""
    op = _fused_linear() if fused else None
    for i, (weight, bias) in enumerate(layers):
        relu = i < len(layers) - 1 or last_relu
        x = x.to(weight.dtype)
        if op is not None:
            x = op(x, weight, bias, "relu" if relu else "none", [], "")
        else:
            x = F.linear(x, weight, bias)
            if relu:
                x = torch.relu(x)
    return x


# ------------------------------------------------------------------------------------ persistence
def _check_plain(value: Any, where: str) -> None:
    """``ValueError`` unless ``value`` is made of dict/list/tuple/str/int/float/bool/None/tensors."""
    if value is None or isinstance(value, (str, int, float, bool, torch.Tensor)):
        return
    if isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            _check_plain(v, f"{where}[{i}]")
        return
    if isinstance(value, dict):
        for k, v in value.items():
            if not isinstance(k, (str, int)):
                raise ValueError(f"{where}: keys must be str or int, got {type(k).__name__}")
            _check_plain(v, f"{where}[{k!r}]")
        return
    raise ValueError(f"{where}: {type(value).__name__} cannot be stored (plain Python types and tensors only)")


def to_bytes(model: ProcCorrNet, config: CorrNetConfig, extra: dict[str, Any] | None = None) -> bytes:
    """A checkpoint: ``{"format", "state_dict", "config", "extra"}`` through ``torch.save``, as bytes.

    ``extra`` (e.g. the group, validation figures, the frame convention) must hold only plain
    Python types and tensors (``ValueError`` otherwise). Tensors are stored on the CPU.
    """
    import io

    extra = {} if extra is None else extra
    if not isinstance(extra, dict):
        raise ValueError(f"extra must be a dict, got {type(extra).__name__}")
    _check_plain(extra, "extra")
    config.validate()
    payload = {
        "format": FORMAT,
        "state_dict": {k: v.detach().to("cpu").clone() for k, v in model.state_dict().items()},
        "config": config.to_dict(),
        "extra": extra,
    }
    buf = io.BytesIO()
    torch.save(payload, buf)
    return buf.getvalue()


def from_bytes(data: bytes, device: str = "cpu", where: str = "checkpoint") -> tuple[ProcCorrNet, CorrNetConfig, dict[str, Any]]:
    """Read :func:`to_bytes` with ``torch.load(weights_only=True)``.

    Returns ``(model in eval mode on device, config (its ``device`` set to the given one), extra)``.
    Data holding anything but plain types and tensors, or not written by :func:`to_bytes`, raise
    ``ValueError`` (naming ``where``).
    """
    import io

    dev = resolve_device(device)
    try:
        payload = torch.load(io.BytesIO(bytes(data)), map_location=dev, weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, AttributeError, TypeError, EOFError, ValueError, OSError) as e:  # truncated or foreign bytes
        raise ValueError(f"{where}: not a weights-only ProcCorrNet checkpoint ({e.__class__.__name__}: {(str(e).splitlines() or [''])[0][:200]})") from e
    if not isinstance(payload, dict) or payload.get("format") != FORMAT or not {"state_dict", "config", "extra"} <= set(payload):
        raise ValueError(f"{where}: not a ProcCorrNet checkpoint (format {FORMAT!r})")
    # The config names where the model now lives (a model trained on CUDA loads on a CPU machine).
    # Checkpoints written before the box frame existed used the uniform one.
    config = CorrNetConfig.from_dict({"frame": "uniform", **dict(payload["config"]), "device": device})
    model = ProcCorrNet(config.local_hidden, config.feature_dim, config.decoder_hidden, config.context_points, config.residual, config.frame)
    state = payload["state_dict"]
    dtype = next(iter(state.values())).dtype if state else torch.float32
    model.to(device=dev, dtype=dtype)
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as e:
        raise ValueError(f"{where}: weights do not fit the configured network: {str(e).splitlines()[0]}") from e
    model.eval()
    return model, config, payload["extra"]


def save(path: str | os.PathLike, model: ProcCorrNet, config: CorrNetConfig, extra: dict[str, Any] | None = None) -> None:
    """Write :func:`to_bytes` to ``path`` atomically (its folder is created)."""
    from proctex.fileio import atomic_write

    data = to_bytes(model, config, extra)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, data)


def load(path: str | os.PathLike, device: str = "cpu") -> tuple[ProcCorrNet, CorrNetConfig, dict[str, Any]]:
    """Read a :func:`save` file (:func:`from_bytes`; ``ValueError`` naming the path)."""
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise ValueError(f"{path}: cannot read the checkpoint ({e.__class__.__name__})") from e
    return from_bytes(data, device=device, where=str(path))


# --------------------------------------------------------------------------------------- sampling
def sample_indices(n: int, k: int, rng: np.random.Generator) -> np.ndarray:
    """``k`` indices into ``n`` points: without replacement when ``n >= k``; otherwise every point
    once plus ``k - n`` repeats drawn with replacement (a max-pool sees every point)."""
    if n >= k:
        return rng.choice(n, size=k, replace=False)
    return np.concatenate([rng.permutation(n), rng.integers(0, n, size=k - n)])
