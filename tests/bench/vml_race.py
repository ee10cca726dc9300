"""How often a fresh process's first sizable ``torch.exp`` comes out low-accuracy, with and without
:func:`proctex.torch_kernels.resolve_vml` (pytorch/pytorch issue 188792: MKL picks a VML function's
kernel on its first call, and concurrent first calls from torch's worker threads can run a
low-accuracy one for a thread's chunk).

Each process uses two torch threads, computes ``exp`` of 65,536 float32 values in (0.01, 3) once,
and prints its largest error relative to float64 numpy; a process is "off" above 1e-6 (float32's
exp is within 1 ULP, about 6e-8). Processes start ``--at-once`` at a time (the race wants a busy
machine). Prints both counts; exits 1 when a resolved process came out off.

    .venv/bin/python tests/bench/vml_race.py [--processes 90] [--at-once 6]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

CHILD = r"""
import sys
import numpy as np
import torch
torch.set_num_threads(2)
if sys.argv[1] == "resolved":
    from proctex.torch_kernels import resolve_vml
    resolve_vml()
x = torch.from_numpy(np.linspace(0.01, 3.0, 65536, dtype=np.float32))
y = torch.exp(x).numpy().astype(np.float64)
ref = np.exp(x.numpy().astype(np.float64))
print(float(np.max(np.abs(y - ref) / ref)))
"""

OFF = 1e-6


def one(mode: str) -> float:
    run = subprocess.run([sys.executable, "-c", CHILD, mode], cwd=ROOT, capture_output=True, text=True, timeout=300, check=True)
    return float(run.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--processes", type=int, default=90, help="processes per mode")
    ap.add_argument("--at-once", type=int, default=6)
    a = ap.parse_args()
    if a.processes < 1 or a.at_once < 1:
        ap.error("--processes and --at-once must be at least 1")
    result = {}
    with ThreadPoolExecutor(a.at_once) as pool:
        for mode in ("cold", "resolved"):
            errors = list(pool.map(one, [mode] * a.processes))
            off = [e for e in errors if e > OFF]
            result[mode] = len(off)
            print(f"{mode:9s} {len(off)} of {len(errors)} processes off (worst relative error {max(errors):.3g})", flush=True)
    return 1 if result["resolved"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
