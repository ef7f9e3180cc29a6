"""Shared fixtures (kept minimal: no options or hooks that change global behaviour)."""

from __future__ import annotations

from typing import Any

import pytest

from golden import load_golden


@pytest.fixture(scope="session")
def golden() -> dict[str, Any]:
    """The decoded Pyrado golden data (``tests/data/pyrado_golden.json``); treat it as read-only."""
    return load_golden()
