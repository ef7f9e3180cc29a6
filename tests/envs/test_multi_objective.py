"""MO-Gymnasium v5 presets: MO-Gymnasium 1.3.2's vector rewards bit for bit, Gymnasium's scalar reward, the table.

The lockstep runs drive ``multi_objective_env`` (both backends) and MO-Gymnasium's own envs
(``gymnasium.make("mo-...-v5")`` after ``import mo_gymnasium``) with the same random actions (float32 for the
preset, their float64 values for MO-Gymnasium, whose control cost is then computed in float64 like the task's),
and hold every step's vector reward to MO-Gymnasium's with ``torch.equal`` on float32 tensors (and on their bits).
The batched backend's references are put into the batched env's state after every reset with
``torchtasks.parity.sync_gymnasium_env`` (as the batched parity tests do); the one-env Gymnasium backend is seeded
as its reference is. Resets are forced in the middle of episodes, so every id resets at least once. The scalar
reward is compared with Gymnasium's, rebuilt from MO-Gymnasium's ``info`` in Gymnasium v5's own order
(``(forward + healthy) - (ctrl_cost + contact_cost)``: checked against plain Gymnasium below), within the
tolerances of the existing parity tests.

The scalarisation table (weights from MO-Gymnasium's docstrings, derived for mo-hopper-2obj-v5 and mo-ant-v5, and
the residual they leave) is written out here from MO-Gymnasium's source, and the test computes the residual from
the collected data's own term entries.
"""

from __future__ import annotations

import math
import pickle
import sys
import warnings
from typing import Any

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco")
gymnasium = pytest.importorskip("gymnasium")

from torchrl.envs import LineariseRewards, RewardSum, Transform  # noqa: E402
from torchrl.envs.utils import check_env_specs  # noqa: E402

from torchtasks.cli import main  # noqa: E402
from torchtasks.envs import multi_objective  # noqa: E402
from torchtasks.envs.multi_objective import (  # noqa: E402
    MULTI_OBJECTIVE_ENV_IDS,
    MULTI_OBJECTIVE_ENVS,
    multi_objective_env,
    multi_objective_record,
    multi_objective_task,
)
from torchtasks.parity import sync_gymnasium_env  # noqa: E402

pytestmark = pytest.mark.mujoco

#: MO-Gymnasium 1.3.2 (mo_gymnasium/envs/mujoco/__init__.py and *_v5.py): id -> (the Gymnasium env its class
#: subclasses, the vector's size)
MO_GYMNASIUM: dict[str, tuple[str, int]] = {
    "mo-halfcheetah-v5": ("HalfCheetah-v5", 2),
    "mo-hopper-v5": ("Hopper-v5", 3),
    "mo-hopper-2obj-v5": ("Hopper-v5", 2),  # cost_objective=False
    "mo-walker2d-v5": ("Walker2d-v5", 2),
    "mo-ant-v5": ("Ant-v5", 3),
    "mo-ant-2obj-v5": ("Ant-v5", 2),  # cost_objective=False
    "mo-swimmer-v5": ("Swimmer-v5", 2),
    "mo-humanoid-v5": ("Humanoid-v5", 2),
}
IDS = list(MO_GYMNASIUM)

#: LineariseRewards' weights for Gymnasium's default keywords, and what they pay beyond Gymnasium's reward:
#: ``{term: c}`` (linearised - scalar = Σ c · term). The docstrings' weights: HalfCheetah [1, 0.1], Hopper
#: [1, 0, 1e-3], Walker2d [1, 1e-3], Swimmer [1, 1e-4], Humanoid [1.25, 0.1], Ant (cost_objective=False) [1, 0].
#: Derived: Hopper-2obj's objectives are [x + ctrl + H, 10 z + ctrl + H] -> [1, 0]; Ant-v5's are
#: [x + H + K, y + H + K, -Σa² + H + K] and ctrl = -0.5 Σa² -> [1, 0, 0.5], leaving 0.5 (H + K).
#: Residuals: Hopper and Walker2d pay H (healthy) also through 1e-3 · (energy + H); Humanoid's x objective carries
#: H + K at 1.25 and its energy one at 0.1: 1.35 (H + K) against Gymnasium's 1 (H + K).
SCALARISATION: dict[str, tuple[tuple[float, ...], dict[str, float]]] = {
    "mo-halfcheetah-v5": ((1.0, 0.1), {}),
    "mo-hopper-v5": ((1.0, 0.0, 1e-3), {"survive": 1e-3}),
    "mo-hopper-2obj-v5": ((1.0, 0.0), {}),
    "mo-walker2d-v5": ((1.0, 1e-3), {"survive": 1e-3}),
    "mo-ant-v5": ((1.0, 0.0, 0.5), {"survive": 0.5, "contact": 0.5}),
    "mo-ant-2obj-v5": ((1.0, 0.0), {}),
    "mo-swimmer-v5": ((1.0, 1e-4), {}),
    "mo-humanoid-v5": ((1.25, 0.1), {"survive": 0.35, "contact": 0.35}),
}

BATCHED_ENVS, BATCHED_STEPS = 10, 100  # 1000 transitions
BATCHED_FORCED = {30: [0], 70: [1, 9]}  # step -> envs reset in the middle of their episodes
#: the one-env backend: 400 steps, resets forced twice (the falling envs also end episodes by themselves); the batched
#: backend above holds the same vectors over 1000 transitions
GYMNASIUM_STEPS = 400
GYMNASIUM_FORCED = (130, 270)
ATOL = {"batched": 1e-9, "gymnasium": 1e-5}  # the scalar reward (float64 / float32 reward spec)
STEPS = 60  # of the scalarisation runs


def gymnasium_scalar(info: dict[str, Any]) -> float:
    """Gymnasium v5's reward from its info, in its order: ``(forward + healthy) - (ctrl_cost + contact_cost)``."""
    rewards = info["reward_forward"] + info.get("reward_survive", 0.0)
    costs = -info["reward_ctrl"] + -info.get("reward_contact", 0.0)
    return float(rewards - costs)


@pytest.fixture(scope="module")
def mo_gymnasium() -> Any:
    return pytest.importorskip("mo_gymnasium")


# ------------------------------------------------------------------------------------------ records
def test_the_ids_are_the_tables_keys_in_order() -> None:
    assert MULTI_OBJECTIVE_ENV_IDS == tuple(MULTI_OBJECTIVE_ENVS) == tuple(IDS)


@pytest.mark.parametrize("env_id", IDS)
def test_records_hold_mo_gymnasiums_base_envs_and_the_scalarisation_table(env_id: str) -> None:
    record = multi_objective_record(env_id)
    base_id, size = MO_GYMNASIUM[env_id]
    weights, residual = SCALARISATION[env_id]
    assert (record.base_id, len(record.objectives)) == (base_id, size)
    assert record.weights == weights and dict(record.residual) == residual
    assert set(record.base.state_keys) <= set(record.state_keys)
    assert multi_objective_task(env_id).group_names == record.objective_names


def test_gymnasium_scalar_rebuilds_gymnasiums_reward_exactly() -> None:
    for base_id in sorted({base for base, _ in MO_GYMNASIUM.values()}):
        env = gymnasium.make(base_id)
        env.reset(seed=0)
        rng = np.random.default_rng(0)
        for _ in range(50):
            _, reward, terminated, truncated, info = env.step(rng.uniform(-0.4, 0.4, env.action_space.shape))
            assert gymnasium_scalar(info) == reward, base_id
            if terminated or truncated:
                env.reset()
        env.close()


# ------------------------------------------------------------------------------------ the lockstep runs
class Run:
    """A lockstep run: the preset's outputs and MO-Gymnasium's ``step`` results, compared when the run is over."""

    def __init__(self) -> None:
        self.resets = self.observation_mismatches = 0
        self.got: dict[str, list[torch.Tensor]] = {key: [] for key in ("vector", "reward", "flags", "observation")}
        self.expected: list[tuple] = []

    def record(self, out: Any, steps: list[tuple]) -> None:
        """``out``: the preset's ``"next"`` of one step (``[n]`` or ``[]``); ``steps``: MO-Gymnasium's results."""
        batch = (lambda x: x) if out.batch_dims else (lambda x: x.unsqueeze(0))
        self.got["vector"].append(batch(out["vector_reward"]))
        self.got["reward"].append(batch(out["reward"])[:, 0])
        self.got["flags"].append(batch(torch.cat([out["terminated"], out["truncated"], out["done"]], -1)))
        self.got["observation"].append(batch(out["observation"]))
        self.expected += steps

    def compare(self) -> dict[str, Any]:
        """The transitions, the vector rewards that are not bit-identical, the largest scalar reward difference,
        the transitions whose flags or observations differ."""
        got = {key: torch.cat(values) for key, values in self.got.items()}
        observations, vectors, terminated, truncated, infos = zip(*self.expected, strict=True)
        vector = torch.from_numpy(np.stack(vectors))
        assert got["vector"].dtype == vector.dtype == torch.float32
        same = (got["vector"] == vector).all(-1) & (got["vector"].view(torch.int32) == vector.view(torch.int32)).all(-1)
        scalar = torch.tensor([gymnasium_scalar(info) for info in infos], dtype=torch.float64)
        flags = torch.from_numpy(np.array([terminated, truncated, np.logical_or(terminated, truncated)])).T
        observation = torch.from_numpy(np.stack(observations))
        return {
            "transitions": len(self.expected),
            "vector_mismatches": [
                f"{got['vector'][i].tolist()} != {vector[i].tolist()}" for i in (~same).nonzero()[:, 0]
            ],
            "reward_diff": float((got["reward"].double() - scalar).abs().max()),
            "flag_mismatches": int((got["flags"] != flags).any(-1).sum()),
            "observation_mismatches": self.observation_mismatches
            + int((got["observation"] != observation).any(-1).sum()),
        }


def run_batched(env_id: str, seed: int = 0, *, env: Any = None) -> Run:
    env = multi_objective_env(env_id, num_envs=BATCHED_ENVS, seed=seed, backend="batched") if env is None else env
    base = env.base_env
    references = [gymnasium.make(env_id, disable_env_checker=True) for _ in range(BATCHED_ENVS)]
    run = Run()
    root = env.reset()

    def sync(i: int, observation: torch.Tensor) -> None:  # a reset env's state into its reference
        run.observation_mismatches += int(not np.array_equal(observation, sync_gymnasium_env(references[i], base, i)))

    for i, reference in enumerate(references):
        reference.reset(seed=seed * BATCHED_ENVS + i)
        sync(i, root["observation"][i].numpy())
    rng = np.random.default_rng(seed)
    low, high = references[0].action_space.low, references[0].action_space.high
    for step in range(BATCHED_STEPS):
        actions = rng.uniform(low, high, size=(BATCHED_ENVS, low.size)).astype(np.float32)
        root["action"] = torch.from_numpy(actions)
        root, next_root = env.step_and_maybe_reset(root)
        out = root["next"]
        run.record(out, [reference.step(actions[i].astype(np.float64)) for i, reference in enumerate(references)])
        for i in out["done"][:, 0].nonzero()[:, 0].tolist():  # TorchRL has reset these envs: follow it
            run.resets += 1
            sync(i, next_root["observation"][i].numpy())
        if step in BATCHED_FORCED:
            mask = torch.zeros(BATCHED_ENVS, 1, dtype=torch.bool)
            mask[BATCHED_FORCED[step]] = True
            next_root = env.reset(next_root.set("_reset", mask))
            for i in BATCHED_FORCED[step]:
                run.resets += 1
                sync(i, next_root["observation"][i].numpy())
        root = next_root
    env.close()
    for reference in references:
        reference.close()
    return run


def run_gymnasium(env_id: str, seed: int = 0) -> Run:
    env = multi_objective_env(env_id, seed=seed, backend="gymnasium")
    reference = gymnasium.make(env_id, disable_env_checker=True)  # the checker warns about a vector reward
    reference.reset(seed=seed)  # what set_seed does to the preset's Gymnasium env; both reset alike from here on
    expected, _ = reference.reset()
    run = Run()
    root = env.reset()
    run.observation_mismatches += int(not np.array_equal(root["observation"].numpy(), expected))
    rng = np.random.default_rng(seed)
    low, high = reference.action_space.low, reference.action_space.high
    for step in range(GYMNASIUM_STEPS):
        action = rng.uniform(low, high).astype(np.float32)
        root["action"] = torch.from_numpy(action)
        root, next_root = env.step_and_maybe_reset(root)
        result = reference.step(action.astype(np.float64))
        run.record(root["next"], [result])
        terminated, truncated = result[2:4]
        if terminated or truncated or step in GYMNASIUM_FORCED:
            run.resets += 1
            expected, _ = reference.reset()
            if not (terminated or truncated):  # forced: restart the preset too
                next_root = env.reset()
            run.observation_mismatches += int(not np.array_equal(next_root["observation"].numpy(), expected))
        root = next_root
    env.close()
    reference.close()
    return run


@pytest.mark.parametrize("backend", ["gymnasium", "batched"])
@pytest.mark.parametrize("env_id", IDS)
def test_vector_rewards_equal_mo_gymnasiums_bit_for_bit(env_id: str, backend: str, mo_gymnasium: Any) -> None:
    run = run_batched(env_id) if backend == "batched" else run_gymnasium(env_id)
    assert run.resets >= 1
    found = run.compare()
    mismatches = found["vector_mismatches"]
    assert found["transitions"] >= (BATCHED_ENVS * BATCHED_STEPS if backend == "batched" else GYMNASIUM_STEPS)
    assert not mismatches, f"{len(mismatches)} of {found['transitions']} vectors differ, first: {mismatches[0]}"
    assert found["reward_diff"] <= ATOL[backend]
    assert found["flag_mismatches"] == 0 and found["observation_mismatches"] == 0


def test_rounding_once_in_float64_is_caught(mo_gymnasium: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    """The variant that sums a group in float64 and rounds once (not after every addition) fails the comparison."""
    monkeypatch.setattr(multi_objective, "VECTOR_REWARD_DTYPE", None)  # float64 sums, written in float64
    env = multi_objective_env("mo-walker2d-v5", num_envs=BATCHED_ENVS, seed=0, backend="batched")
    assert env.output_spec["full_reward_spec", "vector_reward"].dtype == torch.float64
    env.append_transform(_RoundToFloat32())
    found = run_batched("mo-walker2d-v5", env=env).compare()
    assert found["flag_mismatches"] == 0 and found["observation_mismatches"] == 0
    assert len(found["vector_mismatches"]) > 0


class _RoundToFloat32(Transform):
    """Round the float64 vector reward to float32 once (the variant the bit-for-bit test must reject)."""

    def __init__(self) -> None:
        super().__init__(in_keys=[], out_keys=[])

    def _step(self, tensordict: Any, next_tensordict: Any) -> Any:
        return next_tensordict.set("vector_reward", next_tensordict["vector_reward"].to(torch.float32))

    def transform_reward_spec(self, reward_spec: Any) -> Any:
        reward_spec["vector_reward"] = reward_spec["vector_reward"].clone().to(torch.float32)
        return reward_spec


# ------------------------------------------------------------------------------------------ the stack
def linearised_difference(env_id: str, data: Any) -> torch.Tensor:
    """``|LineariseRewards(vector) - (scalar + residual)|`` over collected data, and the float32 bound it must meet."""
    weights, residual = SCALARISATION[env_id]
    linearise = LineariseRewards(
        in_keys=[("next", "vector_reward")], out_keys=[("next", "linear_reward")], weights=weights
    )
    out = linearise(data.clone())["next"]
    vector, linear = out["vector_reward"], out["linear_reward"]
    assert vector.dtype == linear.dtype == torch.float32 and vector.shape[-1] == len(weights)
    expected = out["reward"].double()
    for term, coefficient in residual.items():
        expected = expected + coefficient * out["task_reward", term].double()
    # float32 error bound: each objective is rounded after every addition, and its partial sums are at most
    # |objective| + Σ |terms| (the shared terms are among the data's terms), then LineariseRewards' float32 sum
    terms = sum(out["task_reward", name].double().abs() for name in out["task_reward"].keys())
    partial = vector.double().abs() + terms
    scale = (partial * torch.tensor(weights, dtype=torch.float64).abs()).sum(-1, keepdim=True) + expected.abs()
    difference = (linear.double() - expected).abs()
    assert (difference <= 4 * torch.finfo(torch.float32).eps * scale).all(), float(difference.max())
    return difference


@pytest.mark.parametrize("env_id", IDS)
def test_linearise_rewards_with_the_table_weights_gives_the_scalar_reward_plus_the_residual(env_id: str) -> None:
    env = multi_objective_env(env_id, num_envs=4, seed=3, backend="batched")
    data = env.rollout(STEPS, break_when_any_done=False)
    env.close()
    difference = linearised_difference(env_id, data)
    assert difference.shape == (4, STEPS, 1)
    if SCALARISATION[env_id][1]:  # the residual is real: without it the weights miss Gymnasium's reward
        weights = SCALARISATION[env_id][0]
        linear = (data["next", "vector_reward"].double() * torch.tensor(weights, dtype=torch.float64)).sum(-1)
        assert ((linear - data["next", "reward"][..., 0]).abs() > 1e-4).any()


@pytest.mark.parametrize(("env_id", "backend"), [("mo-hopper-v5", "gymnasium"), ("mo-humanoid-v5", "batched")])
def test_linearise_rewards_and_reward_sum_in_the_preset(env_id: str, backend: str) -> None:
    num_envs = 3 if backend == "batched" else 1
    env = multi_objective_env(env_id, num_envs=num_envs, seed=1, backend=backend)
    weights = SCALARISATION[env_id][0]
    env.append_transform(LineariseRewards(in_keys=["vector_reward"], out_keys=["linear_reward"], weights=weights))
    env.append_transform(RewardSum(in_keys=["linear_reward"], out_keys=["episode_linear_reward"]))
    check_env_specs(env)
    spec = env.output_spec["full_reward_spec"]
    assert spec["vector_reward"].shape[-1] == len(weights) and spec["vector_reward"].dtype == torch.float32
    assert spec["linear_reward"].shape[-1] == 1
    episode_sum = env.observation_spec["episode_vector_reward"]
    assert episode_sum.shape[-1] == len(weights) and episode_sum.dtype == torch.float32
    data = env.rollout(STEPS, break_when_any_done=False)
    env.close()
    data = data if backend == "batched" else data.unsqueeze(0)
    linearised_difference(env_id, data.exclude(("next", "linear_reward")))
    out = data["next"]
    # the preset's RewardSum sums the vector per episode, and the appended one the linearised reward: the same
    # float32 additions, step after step
    vector_total, linear_total = torch.zeros(num_envs, len(weights)), torch.zeros(num_envs, 1)
    for t in range(STEPS):
        vector_total, linear_total = (
            vector_total + out["vector_reward"][:, t],
            linear_total + out["linear_reward"][:, t],
        )
        assert torch.equal(out["episode_vector_reward"][:, t], vector_total)
        assert torch.equal(out["episode_linear_reward"][:, t], linear_total)
        done = out["done"][:, t]
        vector_total, linear_total = torch.where(done, 0.0, vector_total), torch.where(done, 0.0, linear_total)
    assert out["done"].any()  # an episode ended and the sums restarted


@pytest.mark.parametrize("env_id", ["mo-hopper-v5", "mo-ant-2obj-v5"])
def test_a_broken_step_pays_zero_in_the_vector_too(env_id: str) -> None:
    env = multi_objective_env(env_id, num_envs=2, seed=0, backend="batched")
    root = env.reset()
    action = torch.full((2, env.action_spec.shape[-1]), 0.3)
    action[1, 0] = math.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        out = env.step(root.set("action", action))["next"]
    env.close()
    assert out["broken"][:, 0].tolist() == [False, True]
    assert torch.equal(out["vector_reward"][1], torch.zeros(len(SCALARISATION[env_id][0])))
    assert (out["vector_reward"][0] != 0).all()
    assert out["episode_vector_reward"].isfinite().all()
    for name in multi_objective_record(env_id).objective_names:
        assert out["reward_groups", name][1, 0].item() == 0.0


def test_the_task_pickles_with_its_extra_terms() -> None:
    task = multi_objective_task("mo-hopper-v5")
    copy = pickle.loads(pickle.dumps(task))
    state = torch.zeros(1, task.state_size, dtype=torch.float64)
    state[:, 2] = 1.4  # qpos[1]: 0.15 above Hopper's initial height 1.25
    action = torch.full((1, 3), 0.5, dtype=torch.float64)
    for candidate in (task, copy):
        out = candidate.transition(state, action, state, candidate.reset(state))
        height = out.groups["height"]  # 10 · 0.15 + 1 (healthy), rounded to float32 after each addition
        assert height.dtype == torch.float32
        assert height.item() == np.float32(np.float32(10 * (1.4 - 1.25)) + 1.0)


# ------------------------------------------------------------------------------------------ errors
@pytest.mark.parametrize(
    ("env_id", "hint"),
    [("mo-hoper-v5", "did you mean 'mo-hopper-v5'"), ("Hopper-v5", "did you mean 'mo-hopper-v5'"), ("x", "the ids:")],
)
def test_an_unknown_id_names_the_closest_ids(env_id: str, hint: str) -> None:
    with pytest.raises(ValueError, match=f"unknown MO-Gymnasium env '{env_id}'.*{hint}"):
        multi_objective_env(env_id)
    with pytest.raises(TypeError, match="env_id must be a string"):
        multi_objective_task(3)


@pytest.mark.parametrize("env_id", IDS)
def test_ctrl_cost_weight_zero_is_refused_where_mo_gymnasium_divides_by_it(env_id: str) -> None:
    if "energy" in multi_objective_record(env_id).objectives:
        with pytest.raises(ValueError, match=r"ctrl_cost_weight must be > 0 .*0/0.* got 0"):
            multi_objective_env(env_id, ctrl_cost_weight=0.0)
    else:  # the 2obj ids add the weighted control cost to the objectives: a weight of 0 is fine
        task = multi_objective_task(env_id, ctrl_cost_weight=0.0)
        assert task.group_names == multi_objective_record(env_id).objective_names


def test_cost_objective_and_unknown_keywords_are_refused() -> None:
    with pytest.raises(TypeError, match="cost_objective, which the id fixes"):
        multi_objective_task("mo-ant-v5", cost_objective=False)
    with pytest.raises(TypeError, match="unexpected keyword argument"):
        multi_objective_task("mo-ant-v5", no_such_keyword=1)


# ------------------------------------------------------------------------------------------ the command
def _rows(text: str) -> dict[str, dict[str, str]]:
    lines = [line for line in text.splitlines() if line.startswith("|")]
    cells = [[cell.strip() for cell in line.strip().strip("|").split("|")] for line in lines]
    return {row[0]: dict(zip(cells[0], row, strict=True)) for row in cells[2:]}


@pytest.mark.parametrize("backend", ["gymnasium", "batched"])
def test_check_compares_with_mo_gymnasium(backend: str, tmp_path, capsys, mo_gymnasium: Any) -> None:
    env_ids = ["mo-hopper-v5", "mo-ant-v5"] if backend == "gymnasium" else ["mo-humanoid-v5"]
    argv = ["check", *env_ids, "--seeds", "1", "--steps", "30", "--no-progress"]
    assert main([*argv, "--backend", backend, "--output", str(tmp_path)]) == 0
    rows = _rows(capsys.readouterr().out)
    assert set(rows) == set(env_ids)
    for row in rows.values():
        assert (row["backend"], row["vector mism."], row["result"]) == (backend, "0", "PASS")
        assert int(row["resets"]) >= 2  # the forced ones
    assert len(list(tmp_path.glob(f"check_multi_objective_{backend}_*.json"))) == 1


def test_check_reports_a_vector_that_differs(tmp_path, capsys, mo_gymnasium: Any, monkeypatch) -> None:
    monkeypatch.setattr(multi_objective, "VECTOR_REWARD_DTYPE", torch.float64)  # same values, other dtype
    argv = ["check", "mo-swimmer-v5", "--seeds", "1", "--steps", "5", "--no-progress", "--output", str(tmp_path)]
    assert main(argv) == 1
    captured = capsys.readouterr()
    assert _rows(captured.out)["mo-swimmer-v5"]["vector mism."] == "5"
    assert "MO-Gymnasium parity NOT met for: mo-swimmer-v5" in captured.err


def test_check_without_mo_gymnasium_says_how_to_install_it(tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "mo_gymnasium", None)  # import mo_gymnasium raises ImportError
    assert main(["check", "mo-hopper-v5", "--output", str(tmp_path)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    (line,) = captured.err.splitlines()
    assert line.startswith("torchtasks check: mo-hopper-v5 is compared with MO-Gymnasium 1.3.2")
    assert line.endswith("pip install mo-gymnasium==1.3.2 pygame scipy")


def test_check_refuses_mixed_ids_and_suggests_close_ones(tmp_path, capsys) -> None:
    assert main(["check", "Hopper-v5", "mo-hopper-v5", "--output", str(tmp_path)]) == 2
    assert "in separate commands" in capsys.readouterr().err
    assert main(["check", "mo-hoper-v5", "--output", str(tmp_path)]) == 2
    assert "did you mean mo-hopper-v5?" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"backend": "jax"}, ValueError, "backend must be 'gymnasium' or 'batched'"),
        ({"steps": 0}, ValueError, "steps must be a positive int"),
        ({"num_envs": 0, "backend": "batched"}, ValueError, "num_envs must be a positive int"),
        ({"seeds": []}, ValueError, "at least one seed"),
        ({"forced_resets": {3: [2]}}, ValueError, r"env indices in \[0, 1\)"),
        ({"ctrl_cost_weight": 0.0}, ValueError, "ctrl_cost_weight must be > 0"),
    ],
)
def test_check_multi_objective_parity_rejects_bad_arguments(kwargs: dict, error: type, match: str) -> None:
    from torchtasks.parity import check_multi_objective_parity

    with pytest.raises(error, match=match):
        check_multi_objective_parity("mo-swimmer-v5", **kwargs)
