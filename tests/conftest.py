"""Shared fixtures (kept minimal; the one autouse fixture restores global torch state and seeds it per test)."""

from __future__ import annotations

from typing import Any

import pytest

from golden import load_golden


@pytest.fixture(scope="session")
def golden() -> dict[str, Any]:
    """The decoded Pyrado golden data (``tests/data/pyrado_golden.json``); treat it as read-only."""
    return load_golden()


@pytest.fixture(autouse=True)
def _restore_torch_threads(request: pytest.FixtureRequest):
    """Keep torch's global thread count from leaking between tests, and seed torch's global generator per test.

    Multi-process collectors and envs change the thread count, also from finalizers that run whenever garbage
    is collected; dynamo refuses a trace during which it changes. Collect their garbage right after such
    tests and restore the count after every test.

    The global generator (random actions of ``env.rollout()`` without a policy, a fresh ``nn.Linear``) is
    seeded from the test's id: a test draws the same numbers whichever tests ran before it in its worker
    (pytest-xdist distributes them differently from run to run).
    """
    import gc
    import zlib

    import torch

    torch.manual_seed(zlib.crc32(request.node.nodeid.encode()))
    threads = torch.get_num_threads()
    yield
    if request.node.get_closest_marker("multiprocess") is not None:
        gc.collect()
    torch.set_num_threads(threads)


@pytest.fixture
def fork_start_method():
    """Start worker processes by fork (seconds instead of tens of seconds per spawned worker on this machine).

    The constructors the tests hand to workers are module-level functions of the shared helpers, so they are
    spawn-safe too (``transforms/test_transform_collectors.py::test_parallel_env_spawn`` checks one).
    """
    import multiprocessing as mp

    previous = mp.get_start_method(allow_none=True)
    mp.set_start_method("fork", force=True)
    yield
    mp.set_start_method(previous, force=True)
