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


@pytest.fixture(scope="session")
def painted_mug_root(tmp_path_factory) -> Path:
    """A store root holding ``mug``: a painted mug family without networks (the identity mapper
    serves it), built once per test session. Tests that change it work on a copy."""
    from proctex.build.paint import stage_paint
    from proctex.build.sample import stage_sample
    from proctex.build.template import stage_template
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore
    from proctex.store.state import write_config

    base = tmp_path_factory.mktemp("painted_mug")
    cfg = BuildConfig.from_dict(dict(model="mug", n_train=2, n_test=0, texture_size=32, prompt="blue ceramic"))
    st = FamilyStore(base / "mug")
    write_config(st, cfg)
    for stage in (stage_sample, stage_template, stage_paint):
        stage(st, cfg, log=lambda *_: None)
    return base


TOY_METHOD = '''"""A correspondence method in one file: the identity mirrored in x (a wrong map, on purpose)."""
import numpy as np

from proctex.transfer.methods import Method, register


class MirrorMapper:
    def map(self, group, vertices, faces, query, seed=0):
        return np.asarray(query, dtype=np.float64) * np.array([-1.0, 1.0, 1.0])


register(Method("toy_mirror", lambda ctx: MirrorMapper(), "the identity mirrored in x (a test's toy)"))
'''


@pytest.fixture()
def toy_method(tmp_path, monkeypatch):
    """The toy method's file named in PROCTEX_PLUGINS; unregistered afterwards."""
    from proctex import plugins
    from proctex.transfer.methods import unregister

    path = tmp_path / "toy_method.py"
    path.write_text(TOY_METHOD)
    monkeypatch.setenv("PROCTEX_PLUGINS", str(path))
    yield "toy_mirror"
    unregister("toy_mirror")
    plugins._LOADED.pop(str(path), None)
