"""Shared fixtures (kept minimal; the one autouse fixture restores global torch state and seeds it per test)."""

from __future__ import annotations

import os
from typing import Any

import pytest

from reference_venv import dm_control_reference  # noqa: F401  (the fixture of dm_control's reference worker)
from repo_paths import TESTS

# Nothing here imports torch at module level: pytest-xdist's controller process loads this file too, and runs no
# test (importing torch there cost ~4 s of CPU while the two workers start and collect).


@pytest.fixture(scope="session")
def golden() -> dict[str, Any]:
    """The decoded Pyrado golden data (``tests/data/pyrado_golden.json``); treat it as read-only."""
    from golden import load_golden

    return load_golden()


_PROCESS_GARBAGE = {"pending": False}  # whether a test that started processes ran since the last collection


@pytest.fixture(autouse=True)
def _restore_torch_threads(request: pytest.FixtureRequest):
    """Keep torch's global thread count from leaking between tests, and seed torch's global generator per test.

    Multi-process collectors and envs change the thread count, also from finalizers that run whenever garbage
    is collected; dynamo refuses a trace during which it changes. Their garbage is collected before the first
    test that starts no processes after such tests (a full collection takes ~0.3-0.6 s in a test process: once
    per run of consecutive multi-process tests, not after each), and the count is restored after every test.

    The objects a test process holds are frozen (``gc.freeze``) while a test starts processes: a forked worker's
    garbage collection would otherwise visit every object it inherited, copying the whole heap page by page
    (late in a run, with millions of objects held, that made a 2-worker ParallelEnv test 16 s instead of 2 s).

    The global generator (random actions of ``env.rollout()`` without a policy, a fresh ``nn.Linear``) is
    seeded from the test's id: a test draws the same numbers whichever tests ran before it in its worker
    (pytest-xdist distributes them differently from run to run).
    """
    import gc
    import zlib

    import torch

    starts_processes = request.node.get_closest_marker("multiprocess") is not None
    if _PROCESS_GARBAGE["pending"] and not starts_processes:
        threads = torch.get_num_threads()
        gc.collect()
        torch.set_num_threads(threads)
        _PROCESS_GARBAGE["pending"] = False
    torch.manual_seed(zlib.crc32(_ungrouped_id(request.node).encode()))
    threads = torch.get_num_threads()
    if starts_processes:
        gc.freeze()
    yield
    if starts_processes:
        gc.unfreeze()
    _PROCESS_GARBAGE["pending"] |= starts_processes
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


RAY_CLUSTER = "ray_cluster"


@pytest.fixture
def ray_cluster():
    """A local Ray cluster of 2 CPUs, started by the first test that asks for it and shared by the tests that follow.

    Starting a cluster costs ~10 s on this machine, so the tests using it run one after the other
    (:func:`pytest_collection_modifyitems`) and the cluster stops after the last of them
    (:func:`pytest_runtest_teardown`). Mark such tests ``ray`` and ``multiprocess`` and put them in the
    ``multiprocess`` xdist group: then one worker runs them all and starts one cluster.

    Ray's workers inherit the environment ``ray.init`` starts the cluster in: ``tests/`` is put on their
    ``PYTHONPATH`` there (the shared helpers, e.g. ``replay_env``, are what env constructors are pickled by). A
    ``runtime_env`` with the same variable would make Ray start fresh workers for it instead of the ones it has
    ready (~15 s more per test under load).
    """
    ray = pytest.importorskip("ray")
    if not ray.is_initialized():
        previous = os.environ.get("PYTHONPATH")
        os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(TESTS), previous]))
        try:
            ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
        finally:
            if previous is None:
                del os.environ["PYTHONPATH"]
            else:
                os.environ["PYTHONPATH"] = previous
    return ray


def _uses_ray_cluster(item: pytest.Item | None) -> bool:
    return item is not None and RAY_CLUSTER in getattr(item, "fixturenames", ())


_UNGROUPED_ID = pytest.StashKey[str]()


def _apply_xdist_groups(items: list[pytest.Item]) -> None:
    """Make ``--dist loadgroup`` group the tests by their ``xdist_group`` marks again.

    pytest-xdist 3.8 tells its scheduler a test's group by appending ``@<group>`` to the test's id, written to
    ``item._nodeid``; pytest 9.2 reads the id from ``item._id`` instead, so the suffix is lost and every test is
    scheduled on its own: no group holds together (pytest-dev/pytest-xdist#1386). This writes the suffixed id where
    pytest reads it (what pytest-xdist's proposed fix does), and does nothing where pytest already reads it (an
    older pytest, a fixed pytest-xdist) or without loadgroup (no suffix written).
    """
    for item in items:
        grouped = item.__dict__.get("_nodeid")
        if isinstance(grouped, str) and grouped != item.nodeid and grouped.startswith(f"{item.nodeid}@"):
            item.stash[_UNGROUPED_ID] = item.nodeid
            item._id = type(item._id).parse(grouped)


def _ungrouped_id(item: pytest.Item) -> str:
    """The test's id without the ``@<group>`` suffix of ``--dist loadgroup``."""
    return item.stash.get(_UNGROUPED_ID, item.nodeid)


@pytest.hookimpl(trylast=True)  # after pytest-xdist's own hook, which writes the group suffix
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Apply the xdist groups (:func:`_apply_xdist_groups`); run the tests marked ``slow`` first; the tests using
    :func:`ray_cluster` run one after the other, where the first of them was collected.

    Slow tests first: pytest-xdist hands out the groups (largest first), then single tests in this order, so a
    long test (the docs build, an example's run) starts while the other worker still has work, instead of
    running alone at the end.
    """
    _apply_xdist_groups(items)
    items[:] = [item for item in items if item.get_closest_marker("slow")] + [
        item for item in items if not item.get_closest_marker("slow")
    ]
    users = [item for item in items if _uses_ray_cluster(item)]
    if len(users) < 2:
        return
    first = items.index(users[0])
    others = [item for item in items if not _uses_ray_cluster(item)]
    items[:] = others[:first] + users + others[first:]


@pytest.hookimpl(trylast=True)
def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None) -> None:
    """Stop the shared Ray cluster after the last of the consecutive tests using it."""
    if _uses_ray_cluster(item) and not _uses_ray_cluster(nextitem):
        import ray

        ray.shutdown()
