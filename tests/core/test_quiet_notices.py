"""``import torchtasks`` silences TorchRL's InitTracker-only notice and its own import-time deprecations, nothing else.

In process, each test records every warning (``simplefilter("always")``) and then installs the package's
filters in front, as ``import torchtasks`` does in a user's process (pytest resets the filters around every
test). The last test checks the import itself, in a fresh ``python -W error`` process.
"""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import pytest
import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.collectors import Collector
from torchrl.envs import EnvBase, InitTracker, TransformedEnv
from torchrl.modules import GRUModule, LSTMModule

from repo_paths import ROOT
from torchtasks._warnings import QUIET_NOTICES, quiet_torchrl_notices
from torchtasks.envs import PendulumEnv, PointMassEnv

NOTICE = "The env passed to Collector is missing transforms required by the policy ({}). From torchrl v0.15"


@contextmanager
def record(torchtasks_filters: bool = True) -> Iterator[list[warnings.WarningMessage]]:
    """Record every warning of the block; with ``torchtasks_filters``, except what ``import torchtasks`` silences."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if torchtasks_filters:
            quiet_torchrl_notices()
        yield caught


def messages(caught: list[warnings.WarningMessage]) -> list[str]:
    return [f"{item.category.__name__}: {item.message}" for item in caught]


ENVS: dict[str, Callable[[], EnvBase]] = {
    "pendulum": lambda: PendulumEnv(batch_size=[2], seed=0),  # observation of 2 entries, action of 1
    "point_mass": lambda: PointMassEnv(batch_size=[2], seed=0),  # observation of 4 entries, action of 2
}
FEED_FORWARD: dict[str, Callable[[int, int], TensorDictModule]] = {
    "function": lambda obs, act: TensorDictModule(lambda x: x[..., :act].tanh(), ["observation"], ["action"]),
    "linear": lambda obs, act: TensorDictModule(torch.nn.Linear(obs, act), ["observation"], ["action"]),
    "mlp": lambda obs, act: TensorDictSequential(
        TensorDictModule(torch.nn.Linear(obs, 8), ["observation"], ["hidden"]),
        TensorDictModule(torch.nn.Sequential(torch.nn.Tanh(), torch.nn.Linear(8, act)), ["hidden"], ["action"]),
    ),
}


def sizes(env: EnvBase) -> tuple[int, int]:
    return env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1]


@pytest.mark.parametrize("policy_name", sorted(FEED_FORWARD))
@pytest.mark.parametrize("env_name", sorted(ENVS))
def test_feed_forward_policy_notice_is_silenced(env_name: str, policy_name: str) -> None:
    """A Collector of a feed-forward policy warns nothing; without the filters, exactly TorchRL's InitTracker notice."""
    for torchtasks_filters in (False, True):
        env = ENVS[env_name]()
        with record(torchtasks_filters) as caught:
            collector = Collector(env, FEED_FORWARD[policy_name](*sizes(env)), frames_per_batch=4, total_frames=8)
            frames = sum(batch.numel() for batch in collector)
            collector.shutdown()
        assert frames == 8
        texts = messages(caught)
        if torchtasks_filters:
            assert texts == []
        else:  # TorchRL still raises it: the filter is needed
            assert len(texts) == 1 and texts[0].startswith(f"FutureWarning: {NOTICE.format('InitTracker')}"), texts


def recurrent_policy(kind: type[LSTMModule] | type[GRUModule], env: EnvBase) -> TensorDictSequential:
    """The smallest recurrent policy: a one-unit LSTM or GRU cell, then a linear layer to the action."""
    obs, act = sizes(env)
    cell = kind(input_size=obs, hidden_size=1, in_key="observation", out_key="hidden")
    return TensorDictSequential(cell, TensorDictModule(torch.nn.Linear(1, act), ["hidden"], ["action"]))


@pytest.mark.parametrize("kind", [LSTMModule, GRUModule], ids=["lstm", "gru"])
def test_recurrent_policy_notice_still_shows(kind: type[LSTMModule] | type[GRUModule]) -> None:
    """The notice naming the policy's primers (with or without InitTracker) is the user's business: it shows."""
    bare = PendulumEnv(batch_size=[2], seed=0)
    tracked = TransformedEnv(PendulumEnv(batch_size=[2], seed=0), InitTracker())
    for env, missing in ((bare, "InitTracker, TensorDictPrimer"), (tracked, "TensorDictPrimer")):
        with record() as caught:  # use_buffers=False: no policy call at construction (it would need is_init)
            Collector(env, recurrent_policy(kind, env), frames_per_batch=4, total_frames=8, use_buffers=False)
        texts = messages(caught)
        assert len(texts) == 1 and texts[0].startswith(f"FutureWarning: {NOTICE.format(missing)}"), texts


def test_warnings_about_the_users_code_still_show() -> None:
    """Only TorchRL's messages are matched: the same words raised about the user's code, or a user's own
    WeightUpdaterBase subclass, still show; TorchRL's InitTracker-only message does not."""
    from torchrl.collectors import WeightUpdaterBase

    silenced = NOTICE.format("InitTracker") + " ..."
    with record() as caught:
        warnings.warn("my reward is NaN", UserWarning, stacklevel=1)
        warnings.warn(silenced, FutureWarning, stacklevel=1)  # attributed to this test module, not to torchrl
        warnings.warn_explicit(silenced, FutureWarning, "_single.py", 1, module="torchrl.collectors._single")

        class MyWeightUpdater(WeightUpdaterBase):  # deprecated: TorchRL says so, about the user's class
            pass

    texts = messages(caught)
    assert texts[:2] == ["UserWarning: my reward is NaN", f"FutureWarning: {silenced}"]
    assert len(texts) == 3 and texts[2].startswith("DeprecationWarning: Creating MyWeightUpdater which inherits"), texts


def test_pytest_configuration_filters_every_notice(pytestconfig: pytest.Config) -> None:
    """The test suite's pytest filters hold each notice the package silences (pytest resets the package's own)."""
    configured = set()
    for line in pytestconfig.getini("filterwarnings"):
        action, message, category, *_ = line.split(":")
        if action == "ignore":
            configured.add((message, category))
    missing = [notice for notice in QUIET_NOTICES if (notice.message, notice.category.__name__) not in configured]
    assert not missing, f"pyproject.toml's [tool.pytest.ini_options] filterwarnings lacks {missing}"


SCRIPT = """
import torchtasks  # first: its filters go in front of -W error's
import warnings
import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.collectors import Collector
from torchrl.modules import LSTMModule
from torchtasks.envs import PendulumEnv

policy = TensorDictModule(lambda obs: (-2.0 * obs[..., :1]).clamp(-2.0, 2.0), ["observation"], ["action"])
collector = Collector(PendulumEnv(batch_size=[2], seed=0), policy, frames_per_batch=4, total_frames=8)
print("frames:", sum(batch.numel() for batch in collector))
collector.shutdown()
lstm = LSTMModule(input_size=2, hidden_size=1, in_key="observation", out_key="hidden")
recurrent = TensorDictSequential(lstm, TensorDictModule(torch.nn.Linear(1, 1), ["hidden"], ["action"]))
try:
    Collector(PendulumEnv(batch_size=[2], seed=0), recurrent, frames_per_batch=4, total_frames=8, use_buffers=False)
except FutureWarning as error:
    print("recurrent:", str(error)[:90])
try:
    warnings.warn("my own", UserWarning)
except UserWarning as error:
    print("user:", error)
"""


@pytest.mark.slow  # a fresh interpreter imports torch and TorchRL: ~10 s of CPU
def test_import_silences_the_notices_under_w_error() -> None:
    """``python -W error``: the feed-forward Collector runs; the recurrent notice and a user's warning raise."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT / "src"), os.environ.get("PYTHONPATH")])))
    command = [sys.executable, "-W", "error", "-c", SCRIPT]
    result = subprocess.run(command, capture_output=True, text=True, timeout=300, check=False, env=env)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines() == [
        "frames: 8",
        "recurrent: " + NOTICE.format("InitTracker, TensorDictPrimer")[:90],
        "user: my own",
    ]
    assert result.stderr == ""
