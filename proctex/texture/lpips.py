"""LPIPS (Zhang et al. 2018, "The Unreasonable Effectiveness of Deep Features as a Perceptual
Metric"), AlexNet variant, from a local weights file; nothing is downloaded.

The network: the five convolution blocks of AlexNet (torchvision's ``features`` layout), features
taken after each ReLU, unit-normalised over channels, their differences weighted per channel by
non-negative 1x1 "linear" layers, squared, averaged over space and summed over the five layers.
Inputs are RGB in [-1, 1] after the LPIPS scaling layer.

The weights file is one ``torch.save``d state dict with torchvision AlexNet's backbone keys
``features.{0,3,6,8,10}.{weight,bias}`` and the LPIPS package's heads ``lin{0..4}.model.1.weight``
(the two published files merged: ``{**alexnet.state_dict(), **torch.load("lpips/weights/v0.1/alex.pth")}``
with the backbone keys kept as ``features.*``).
"""

from __future__ import annotations

import os

import numpy as np
import torch
from torch import nn
from proctex.torch_kernels import resolve_vml

resolve_vml()  # MKL's kernels chosen on one thread (see proctex.torch_kernels)

#: (in, out, kernel, stride, padding, max-pool before) of AlexNet's convolutions, torchvision indices.
ALEXNET = {0: (3, 64, 11, 4, 2, False), 3: (64, 192, 5, 1, 2, True), 6: (192, 384, 3, 1, 1, True), 8: (384, 256, 3, 1, 1, False), 10: (256, 256, 3, 1, 1, False)}
SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)


class LPIPS(nn.Module):
    """The AlexNet LPIPS distance. Build with :meth:`load` from a weights file (or with random weights
    for tests); ``distance(a, b)`` of two (H, W, 3) uint8 images."""

    def __init__(self) -> None:
        super().__init__()
        self.features = nn.ModuleDict({str(i): nn.Conv2d(cin, cout, k, stride=s, padding=p) for i, (cin, cout, k, s, p, _) in ALEXNET.items()})
        self.lins = nn.ModuleList([nn.Conv2d(cout, 1, 1, bias=False) for (_, cout, *_rest) in ALEXNET.values()])
        self.register_buffer("shift", torch.tensor(SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(SCALE).view(1, 3, 1, 1))

    @staticmethod
    def load(path: str | os.PathLike, device: str = "cpu") -> "LPIPS":
        """Weights from a local file (module docstring); a missing file or missing / misshapen keys
        are a ``ValueError``."""
        if not os.path.isfile(path):
            raise ValueError(f"LPIPS weights file {str(path)!r} not found")
        try:
            state = torch.load(path, map_location=device, weights_only=True)
        except Exception as exc:
            raise ValueError(f"cannot read LPIPS weights {str(path)!r}: {exc}") from exc
        model = LPIPS()
        mine = {}
        for i in ALEXNET:
            for kind in ("weight", "bias"):
                mine[f"features.{i}.{kind}"] = f"features.{i}.{kind}"
        for k in range(len(ALEXNET)):
            mine[f"lins.{k}.weight"] = f"lin{k}.model.1.weight"
        missing = [theirs for theirs in mine.values() if theirs not in state]
        if missing:
            raise ValueError(f"LPIPS weights {str(path)!r} lack {', '.join(missing[:4])}{' ...' if len(missing) > 4 else ''}")
        target = model.state_dict()
        loaded = {}
        for ours, theirs in mine.items():
            t = state[theirs]
            if tuple(t.shape) != tuple(target[ours].shape):
                raise ValueError(f"LPIPS weights: {theirs} has shape {tuple(t.shape)}, expected {tuple(target[ours].shape)}")
            loaded[ours] = t
        model.load_state_dict({**target, **loaded})
        return model.to(device).eval()

    def _taps(self, x: torch.Tensor) -> list[torch.Tensor]:
        x = (x - self.shift) / self.scale
        out = []
        for i, (_, _, _, _, _, pool) in ALEXNET.items():
            if pool:
                x = nn.functional.max_pool2d(x, 3, 2)
            x = torch.relu(self.features[str(i)](x))
            out.append(x)
        return out

    @torch.no_grad()
    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """(N,) distances of (N, 3, H, W) images in [-1, 1]."""
        total = torch.zeros(a.shape[0], device=a.device)
        for lin, fa, fb in zip(self.lins, self._taps(a), self._taps(b)):
            na = fa / (fa.norm(dim=1, keepdim=True) + 1e-10)
            nb = fb / (fb.norm(dim=1, keepdim=True) + 1e-10)
            total += lin((na - nb) ** 2).mean(dim=(1, 2, 3))
        return total

    def distance(self, a: np.ndarray, b: np.ndarray) -> float:
        """LPIPS of two (H, W, 3) uint8 images (at least 32 pixels a side)."""
        ims = []
        for im in (a, b):
            im = np.asarray(im)
            if im.ndim != 3 or im.shape[2] != 3 or im.dtype != np.uint8 or min(im.shape[:2]) < 32:
                raise ValueError(f"LPIPS needs (H, W, 3) uint8 images of at least 32 px a side, got {im.shape} {im.dtype}")
            ims.append(torch.from_numpy(im.astype(np.float32) / 127.5 - 1.0).permute(2, 0, 1)[None])
        dev = self.shift.device
        return float(self(ims[0].to(dev), ims[1].to(dev))[0])
