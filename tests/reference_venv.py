"""The dm_control reference for the tests: a fixture yielding the running worker, or skipping with the reason.

dm-control 1.0.50 runs on MuJoCo 3.17.0 in the reference venv (``make test`` builds ``.venv-dmc`` when it can;
``TORCHTASKS_DM_CONTROL_PYTHON`` names another python), through ``torchtasks.envs.control_suite.reference``. The
fixture is registered in ``conftest.py``; tests using it are marked ``dm_control_reference`` and share one worker
per test process (group them with ``pytest.mark.xdist_group("dm_control_reference")``).
"""

from __future__ import annotations

from typing import Any

import pytest

# Nothing here imports torch or torchtasks at module level: conftest.py imports this module.


@pytest.fixture(scope="session")
def dm_control_reference() -> Any:
    """The process's running ``DmControlReference`` (``shared_reference()``); skips with the reason without one."""
    from torchtasks.envs.control_suite.reference import DmControlUnavailableError, shared_reference

    try:
        return shared_reference()
    except DmControlUnavailableError as error:
        pytest.skip(str(error))
