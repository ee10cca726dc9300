import os
import shutil
from pathlib import Path

import pytest

SOFA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "procedural_sofa"


@pytest.fixture(scope="session")
def sofa_dir() -> Path:
    if not SOFA.is_dir():
        pytest.skip(f"sofa data not found at {SOFA}")
    return SOFA


def require_validator() -> bool:
    """Whether GLBs can be run through the Khronos glTF validator here. Where npm exists the
    validator must be installed (``make setup`` does it): its absence fails the test instead of
    passing it unchecked. Without npm: False, and the test checks what it can without it."""
    from proctex.texture.export import validator_available

    if validator_available():
        return True
    if shutil.which("npm"):
        pytest.fail("the Khronos glTF validator is missing although npm is here: run `make setup`")
    return False
