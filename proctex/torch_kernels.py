"""torch's MKL math kernels chosen once, on one thread, before its worker threads use them.

PyTorch's x86 wheels route contiguous float32/float64 unary ops (``exp``, ``sqrt``, ``sin``, ``log``,
``tanh``, ...) to MKL's vector math library (VML), called from each intra-op worker thread on its
chunk of the tensor with high accuracy requested. The MKL bundled with the wheels picks each VML
function's kernel (instruction set, accuracy) lazily on the function's first call; when that first
call runs on several threads at once, one thread can run a low-accuracy kernel for its whole chunk
(pytorch/pytorch issue 188792). What it looks like: in a fresh process, the first sizable
``torch.exp`` of 65,536 float32 values with two threads came out 1.5e-4 relative off (about 1,200
float32 ULPs) in the second thread's half, in 1 of 90 processes started six at a time on a 2-core
machine (and once in CI); the same call is exact to 1 ULP from its second call on, so reruns never
show it.

:func:`resolve_vml` calls each VML-routed function once on a one-element tensor of each precision (a
one-element op runs on the calling thread only), so every later call finds its kernel chosen. The
modules that compute with torch call it when they are imported; it costs about a millisecond once a
process. ``tests/bench/vml_race.py`` starts fresh processes with and without it and counts the ones
whose results are off.
"""

from __future__ import annotations

import threading

#: The unary functions ATen hands to MKL's VML for float32 and float64 tensors (``aten/src/ATen/cpu/vml.h``).
VML_FUNCTIONS = ("acos", "asin", "atan", "cos", "erf", "erfc", "erfinv", "exp", "log", "log10", "log2", "sin", "sqrt", "tan", "tanh", "trunc")

_LOCK = threading.Lock()
_DONE: list[bool] = []


def resolve_vml() -> bool:
    """Call every function of :data:`VML_FUNCTIONS` once on a one-element float32 and float64 tensor
    (on this thread), the first time in this process; later calls return at once. Returns True when
    this call did the work. Safe to call from several threads (a lock)."""
    if _DONE:
        return False
    with _LOCK:
        if _DONE:
            return False
        import torch

        for dtype in (torch.float32, torch.float64):
            one = torch.full((1,), 0.5, dtype=dtype)
            for name in VML_FUNCTIONS:
                getattr(torch, name)(one)
        _DONE.append(True)
        return True
