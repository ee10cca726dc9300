"""ProcTex: consistent text-driven texturing of procedural 3D shape families.

An implementation of Xu, Zhu, Ahlbrand, Sridhar and Ritchie, "ProcTex: Consistent and Interactive
Text-to-texture Synthesis for Part-based Procedural Models", arXiv:2501.17895 (2025),
https://arxiv.org/abs/2501.17895. ``__version__`` is the installed distribution's version (semantic
versioning; CHANGELOG.md lists each release).
"""

from __future__ import annotations


def _version() -> str:
    """The version of the installed ``proctex`` distribution (pyproject.toml's, also for an editable
    install); "0+unknown" when the package runs from a tree that was never installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("proctex")
    except PackageNotFoundError:
        return "0+unknown"


__version__ = _version()
