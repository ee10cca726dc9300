import os
from pathlib import Path

import pytest

SOFA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "procedural_sofa"


@pytest.fixture(scope="session")
def sofa_dir() -> Path:
    if not SOFA.is_dir():
        pytest.skip(f"sofa data not found at {SOFA}")
    return SOFA
