"""Paths of the repository for the tests in every subfolder of ``tests/`` (they sit at different depths)."""

from __future__ import annotations

from pathlib import Path

TESTS = Path(__file__).resolve().parent
"""``tests/``: the shared helpers (``golden.py``, ``task_trees.py``, ...), ``conftest.py`` and ``data/``."""

ROOT = TESTS.parent
"""The repository root (``README.md``, ``docs/``, ``examples/``, ``benchmarks/``)."""
