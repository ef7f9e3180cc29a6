"""``torchtasks check ENV_ID --backend batched``: the batched preset against plain Gymnasium, and its failures.

The check (:func:`torchtasks.parity.check_batched_parity`) drives ``gymnasium_env(..., backend="batched")``
and one ``gymnasium.make`` env per batch entry in lockstep, with partial resets forced mid-episode, and
reports the largest differences. These tests run it through the command line for two env ids, then
inject differences into the batched side (by monkeypatching; the forbidden-to-edit env and transform
are only wrapped) and check that each one is reported in its own column, as FAIL, with exit code 1:
a perturbed observation, a control cost weight the reference does not have, a forward weight off by
1e-8 (just above the 1e-9 tolerance), a shorter time limit (truncation) and a partial reset that
resets every env.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco")
gymnasium = pytest.importorskip("gymnasium")

from torchtasks import parity  # noqa: E402
from torchtasks.cli import main  # noqa: E402
from torchtasks.envs import BatchedMujocoEnv  # noqa: E402
from torchtasks.envs.locomotion import gymnasium_env  # noqa: E402

pytestmark = pytest.mark.mujoco

TOLERANCE = 1e-9
#: columns of the batched table holding differences (the term columns: TERM_NAMES)
DIFFERENCE_COLUMNS = (
    "max abs observation diff",
    "max abs reward diff",
    "max abs `forward` diff",
    "max abs `ctrl` diff",
    "max abs `contact` diff",
    "max abs `survive` diff",
    "max abs terminated diff",
    "max abs truncated diff",
)


def _rows(text: str) -> dict[str, dict[str, str]]:
    """The Markdown table rows of ``text`` as ``{env: {column: cell}}``."""
    lines = [line for line in text.splitlines() if line.startswith("|")]
    cells = [[cell.strip() for cell in line.strip().strip("|").split("|")] for line in lines]
    header, body = cells[0], cells[2:]
    return {row[0]: dict(zip(header, row, strict=True)) for row in body}


def _value(cell: str) -> float:
    return 0.0 if cell == "–" else float(cell)


@pytest.fixture(autouse=True)
def _run_in_a_temporary_directory(tmp_path, monkeypatch) -> None:
    """``check`` writes its details under ``runs/check/`` of the working directory: keep the checkout clean."""
    monkeypatch.chdir(tmp_path)


def _check(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, dict[str, dict[str, str]], str]:
    code = main(["check", *argv, "--backend", "batched", "--table", "full"])
    captured = capsys.readouterr()
    return code, _rows(captured.out), captured.err


# ------------------------------------------------------------------------------------ passing
def test_check_backend_batched_passes_for_two_env_ids(capsys: pytest.CaptureFixture[str]) -> None:
    code, rows, err = _check(["Hopper-v5", "Ant-v5", "--seeds", "1", "--steps", "150", "--envs", "3"], capsys)
    assert code == 0, err
    assert set(rows) == {"Hopper-v5", "Ant-v5"}
    for env_id, row in rows.items():
        assert row["result"] == "PASS", row
        assert row["envs"] == "3" and row["steps"] == "150" and row["seeds"] == "0"
        assert row["forced resets"] == "3"  # env 0 after step 50, envs 0 and 2 after step 100
        for column in DIFFERENCE_COLUMNS:
            assert _value(row[column]) <= TOLERANCE, (env_id, column, row[column])
        assert row["max abs observation diff"] == "0"  # the simulations stay in lockstep, bit for bit
    assert rows["Hopper-v5"]["max abs `contact` diff"] == "–"  # Hopper has no contact term
    assert int(rows["Hopper-v5"]["episodes"]) > 0  # random actions: Hopper falls, TorchRL resets it
    assert err == ""


def test_check_batched_parity_result() -> None:
    row = parity.check_batched_parity("Walker2d-v5", seeds=[0, 1], steps=80, num_envs=2, healthy_reward=2.0)
    assert row["env"] == "Walker2d-v5" and row["kwargs"] == {"healthy_reward": 2.0}
    assert row["seeds"] == [0, 1] and row["num_envs"] == 2
    assert row["steps"] == 160 and row["transitions"] == 320
    assert row["forced_resets"] == 2 * 3  # per seed: env 0, then envs 0 and 1
    assert set(row["max_abs_term_diff"]) == {"forward", "ctrl", "survive"}
    assert row["passed"] and row["first_mismatch"] is None
    assert row["episodes"] == row["terminated"] + row["truncated"] > 0
    assert parity.batched_parity_passed(row)


def test_default_forced_resets_happen_mid_episode() -> None:
    assert parity._default_forced_resets(150, 3) == {50: [0], 100: [0, 2]}
    assert parity._default_forced_resets(1, 1) == {0: [0]}
    assert parity._default_forced_resets(2, 2) == {0: [0], 1: [0, 1]}


# -------------------------------------------------------------------------- injected differences
def _perturbed_step(original: Any) -> Any:
    def step(self: BatchedMujocoEnv, tensordict: Any) -> Any:
        out = original(self, tensordict)
        out["observation"][1, 0] += 1e-7  # env 1's first observation entry
        return out

    return step


def test_an_observation_difference_fails(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(BatchedMujocoEnv, "_step", _perturbed_step(BatchedMujocoEnv._step))
    code, rows, err = _check(["HalfCheetah-v5", "--seeds", "1", "--steps", "20"], capsys)
    assert code == 1
    row = rows["HalfCheetah-v5"]
    assert row["result"] == "FAIL"
    assert 5e-8 < float(row["max abs observation diff"]) < 2e-7
    for column in DIFFERENCE_COLUMNS[1:]:  # the task reads qpos, not the observation
        assert _value(row[column]) <= TOLERANCE, column
    assert "HalfCheetah-v5: FAIL, first difference above the tolerance: observation differs" in err
    assert "at env 1 step 0" in err
    assert "batched parity NOT met (tolerance 1e-09) for: HalfCheetah-v5" in err


def _preset_with(**changed: Any) -> Any:
    def make(env_id: str, **kwargs: Any) -> Any:
        return gymnasium_env(env_id, **{**kwargs, **changed})

    return make


@pytest.mark.parametrize(
    ("changed", "columns", "low", "high"),
    [
        ({"ctrl_cost_weight": 0.5}, ("max abs `ctrl` diff", "max abs reward diff"), 1e-2, 10.0),
        ({"forward_reward_weight": 1.0 + 1e-8}, ("max abs `forward` diff", "max abs reward diff"), 1e-9, 1e-6),
    ],
    ids=["ctrl-weight", "forward-weight-1e-8"],
)
def test_a_reward_difference_fails(
    changed: dict[str, float],
    columns: tuple[str, ...],
    low: float,
    high: float,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The preset gets a keyword the reference does not: only the reward columns it changes differ."""
    monkeypatch.setattr(parity, "gymnasium_env", _preset_with(**changed))
    code, rows, err = _check(["Hopper-v5", "Swimmer-v5", "--seeds", "1", "--steps", "30"], capsys)
    assert code == 1
    for env_id, row in rows.items():
        assert row["result"] == "FAIL", env_id
        for column in DIFFERENCE_COLUMNS:
            value = _value(row[column])
            if column in columns:
                assert low < value < high, (env_id, column, value)
            else:
                assert value <= TOLERANCE, (env_id, column, value)
    assert "batched parity NOT met (tolerance 1e-09) for: Hopper-v5, Swimmer-v5" in err


def test_a_truncation_difference_fails(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """The preset's time limit cut to 25 steps (Gymnasium keeps 1000): the truncated column shows it."""
    import torchtasks.envs.locomotion as locomotion

    monkeypatch.setattr(locomotion, "MAX_EPISODE_STEPS", 25)
    code, rows, err = _check(["HalfCheetah-v5", "--seeds", "1", "--steps", "40"], capsys)
    assert code == 1
    row = rows["HalfCheetah-v5"]
    assert row["result"] == "FAIL"
    assert row["max abs truncated diff"] == "1"
    assert row["max abs terminated diff"] == "0"
    assert row["max abs observation diff"] == "0"  # the reference follows the batched env's reset
    assert "truncated differs by 1 at env " in err


def test_a_partial_reset_that_resets_every_env_fails(monkeypatch: pytest.MonkeyPatch) -> None:
    original = BatchedMujocoEnv._reset

    def reset_all(self: BatchedMujocoEnv, tensordict: Any = None, **kwargs: Any) -> Any:
        if tensordict is not None and "_reset" in tensordict.keys():
            tensordict = tensordict.exclude("_reset")  # ignore the mask: reset everything
        return original(self, tensordict, **kwargs)

    monkeypatch.setattr(BatchedMujocoEnv, "_reset", reset_all)
    row = parity.check_batched_parity("HalfCheetah-v5", seeds=[0], steps=30, num_envs=3)
    assert not row["passed"]
    assert row["partial_reset_problems"] == 2
    assert row["first_mismatch"] == "the forced reset of envs [0] after step 10 changed other envs"
    assert not parity.batched_parity_passed(row)


def test_float32_reference_actions_show_gymnasiums_float32_control_cost() -> None:
    """Handing Gymnasium the float32 actions themselves: its float32 control cost exceeds 1e-9, nothing else."""
    env = gymnasium_env("Ant-v5", num_envs=2, seed=0, backend="batched")
    row = parity.compare_batched_with_gymnasium(env, 20, float64_reference_actions=False)
    assert not row["passed"]
    assert 1e-9 < row["max_abs_term_diff"]["ctrl"] < 1e-6
    assert row["max_abs_diff"]["observation"] == 0.0
    assert 1e-9 < row["max_abs_diff"]["reward"] < 1e-6
    assert row["first_mismatch"].startswith("reward differs by ")


# ------------------------------------------------------------------------------------- sync
def test_sync_gymnasium_env_copies_the_state_and_restarts_the_time_limit() -> None:
    env = BatchedMujocoEnv("Walker2d-v5", 2, seed=3)
    tensordict = env.reset()
    for _ in range(5):
        tensordict = env.rand_step(tensordict)["next"]
    reference = gymnasium.make("Walker2d-v5", max_episode_steps=7)
    for _ in range(3):  # an episode under way in the reference: sync starts a fresh one
        reference.reset(seed=0)
        reference.step(reference.action_space.sample())
    observation = parity.sync_gymnasium_env(reference, env, 1)
    np.testing.assert_array_equal(reference.unwrapped.data.qpos, env.batch.qpos[1])
    np.testing.assert_array_equal(reference.unwrapped.data.qvel, env.batch.qvel[1])
    np.testing.assert_array_equal(observation, tensordict["observation"][1].numpy())
    truncated = [reference.step(np.zeros(6))[3] for _ in range(7)]
    assert truncated == [False] * 6 + [True]
    reference.close()
    env.close()


# -------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"seeds": []}, ValueError, "seeds"),
        ({"steps": 0}, ValueError, "steps"),
        ({"num_envs": 0}, ValueError, "num_envs"),
        ({"forced_resets": {3: [2]}}, ValueError, "forced_resets"),
        ({"forced_resets": {-1: [0]}}, ValueError, "forced_resets"),
        ({"forced_resets": [0]}, TypeError, "forced_resets"),
        ({"no_such_keyword": 1}, TypeError, "no_such_keyword"),
    ],
)
def test_check_batched_parity_rejects_bad_arguments(kwargs: dict[str, Any], error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        parity.check_batched_parity("Swimmer-v5", **{"num_envs": 2, **kwargs})


def test_compare_and_sync_reject_bad_arguments() -> None:
    from torchrl.envs import TransformedEnv

    env = BatchedMujocoEnv("Swimmer-v5", 2, seed=0)
    with pytest.raises(TypeError, match="env"):
        parity.compare_batched_with_gymnasium(env, 5)  # not wrapped with a task
    with pytest.raises(ValueError, match="TaskTransform"):
        parity.compare_batched_with_gymnasium(TransformedEnv(env), 5)
    preset = gymnasium_env("Swimmer-v5", num_envs=2, seed=0)
    for kwargs, match in (({"steps": 0}, "steps"), ({"seed": -1}, "seed"), ({"tolerance": -1.0}, "tolerance")):
        with pytest.raises(ValueError, match=match):
            parity.compare_batched_with_gymnasium(preset, **{"steps": 5, **kwargs})
    reference = gymnasium.make("Swimmer-v5")
    with pytest.raises(ValueError, match="index"):
        parity.sync_gymnasium_env(reference, env, 2)
    with pytest.raises(TypeError, match="env"):
        parity.sync_gymnasium_env(reference, preset, 0)
    with pytest.raises(TypeError, match="reference"):
        parity.sync_gymnasium_env(object(), env, 0)
    with pytest.raises(TypeError, match="row"):
        parity.batched_parity_passed([0.0])
    with pytest.raises(ValueError, match="max_abs_term_diff"):
        parity.format_batched_parity_table([{"env": "Swimmer-v5", "seeds": [0], "steps": 1, "max_abs_diff": {}}])
    reference.close()
    preset.close()
    env.close()


def test_envs_option_needs_the_batched_backend(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", "Hopper-v5", "--envs", "2"]) == 2
    assert "--envs applies to --backend batched and to Control Suite tasks only" in capsys.readouterr().err


def test_help_names_the_batched_tolerance(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["check", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "--backend {gymnasium,batched}" in help_text and "--envs" in help_text
    match = re.search(r"flags within ([0-9.e+-]+)\)", help_text)
    assert match is not None and float(match.group(1)) == parity.BATCHED_PARITY_TOLERANCE


def test_nan_differences_count_as_infinite() -> None:
    assert parity._difference([1.0, float("nan")], [1.0, 2.0]) == float("inf")
    assert parity._difference(float("nan"), float("nan")) == 0.0
    assert parity._difference([1.0, 2.0], [1.0]) == float("inf")
    assert parity._difference(torch.tensor([1.5]).numpy(), [1.0]) == 0.5
