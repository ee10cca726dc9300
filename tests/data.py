"""Where the third-party data sets the tests and benchmarks use are (docs/data.md names each one's
public source): ``$PROCTEX_DATA``, else a ``shared/data`` folder beside this repository's checkout.
Tests that need them skip when they are absent."""

from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("PROCTEX_DATA") or ROOT.parent / "shared" / "data")
SOFA = DATA / "procedural_sofa"  # the ProcTex paper's sofa export: train/ and inference/ OBJ + JSON
BLENDS = DATA / "blend"  # third-party Geometry Nodes .blend files and their parameter specs
