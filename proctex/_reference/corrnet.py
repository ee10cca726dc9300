"""Slow, literal reference of :meth:`proctex.correspond.corrnet.ProcCorrNet.decode`, which the tests compare
the shipped split first layer with; not used by the library."""

from __future__ import annotations

import torch

from proctex.correspond.corrnet import ProcCorrNet
from proctex.torch_kernels import resolve_vml

resolve_vml()  # MKL's kernels chosen on one thread (see proctex.torch_kernels)


def decode_reference(model: ProcCorrNet, query: torch.Tensor, global_feature: torch.Tensor) -> torch.Tensor:
    """:meth:`ProcCorrNet.decode` spelled out: concatenate ``[local | global]`` (512-d) per point
    and run the whole decoder on it."""
    q, g = model._split(query, global_feature)
    local = model.local(q)
    out = model.decoder(torch.cat([local, g[:, None, :].expand(-1, local.shape[1], -1)], dim=-1))
    out = out + q if model.residual else out
    return out * model.template_extent if model.frame == "box" else out
