"""The ``proctex`` command line (:func:`main`): the parser and the runner in ``app``, the commands on
shapes in ``shapes`` and on families in ``families``."""

from .app import build_parser, main, run

__all__ = ["build_parser", "main", "run"]
