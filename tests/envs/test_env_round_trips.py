"""Deep copies, pickles and ``.to(device)`` of every env in ``torchtasks.envs``, and the life of a closed env.

A copy (``copy.deepcopy`` or ``pickle.loads(pickle.dumps(env))``) must be an independent env in the
same state: stepped, partially reset and reset with the same actions as the original, it returns
the same tensors, bit for bit. For :class:`~torchtasks.envs.BatchedMujocoEnv` that covers its
thread pool (rebuilt, not shared), its ``MjData`` (with the constraint solver's warm start), its
gather buffers (the observation of the envs a partial reset leaves alone is read from them) and
its per-env generators. ``env.to(device)`` must move the outputs of the next step, not only the
specs: a CPU-only machine checks that on the ``meta`` device (TorchRL cannot move a bounded action
spec to ``meta``, so the spec move is stubbed; everything else is ``EnvBase.to``), a GPU machine
on CUDA as well.
"""

from __future__ import annotations

import copy
import importlib.util
import pickle
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Composite
from torchrl.envs import EnvBase

import torchtasks.envs
from torchtasks._checks import check_positive_int
from torchtasks.envs import PendulumEnv, PointMassEnv

HAS_MUJOCO = importlib.util.find_spec("mujoco") is not None and importlib.util.find_spec("gymnasium") is not None
needs_mujoco = [
    pytest.mark.mujoco,
    pytest.mark.skipif(not HAS_MUJOCO, reason="needs the mujoco extra (mujoco, gymnasium)"),
]
#: the env classes of torchtasks.envs that need the mujoco extra
MUJOCO_ENVS = ("BatchedMujocoEnv",)


def _batched(env_id: str) -> Callable[[], EnvBase]:
    def make() -> EnvBase:
        from torchtasks.envs import BatchedMujocoEnv

        return BatchedMujocoEnv(env_id, 4, seed=0, num_threads=2)

    return make


#: (id, env class name, factory): every env class of torchtasks.envs, the batched env for envs with
#: few and with many gathered MuJoCo arrays (HalfCheetah: qpos only; Ant: xpos and contact forces;
#: Humanoid: xipos, cinert, cvel, qfrc_actuator, cfrc_ext)
ENVS: list[Any] = [
    pytest.param("PendulumEnv", lambda: PendulumEnv(batch_size=[3], seed=0), id="PendulumEnv"),
    pytest.param("PointMassEnv", lambda: PointMassEnv(batch_size=[3], seed=0), id="PointMassEnv"),
    *(
        pytest.param("BatchedMujocoEnv", _batched(env_id), id=f"BatchedMujocoEnv-{env_id}", marks=needs_mujoco)
        for env_id in ("HalfCheetah-v5", "Ant-v5", "Humanoid-v5")
    ),
]

ROUND_TRIPS = {
    "deepcopy": copy.deepcopy,
    "pickle": lambda env: pickle.loads(pickle.dumps(env)),
}


def _assert_same(a: TensorDictBase, b: TensorDictBase, where: str) -> None:
    keys = sorted(map(str, a.keys(True, True)))
    assert keys == sorted(map(str, b.keys(True, True))), where
    for key in a.keys(True, True):
        x, y = a.get(key), b.get(key)
        assert x.dtype == y.dtype and x.device == y.device, f"{where}: {key}"
        assert torch.equal(x, y), f"{where}: {key} differs"


def _actions(env: EnvBase, steps: int) -> list[torch.Tensor]:
    """A fixed sequence of actions inside the action bounds."""
    generator = torch.Generator().manual_seed(0)
    spec = env.action_spec
    low, high = spec.space.low.cpu(), spec.space.high.cpu()
    return [(low + (high - low) * torch.rand(spec.shape, generator=generator)).to(spec.dtype) for _ in range(steps)]


def _reset_mask(env: EnvBase) -> torch.Tensor:
    mask = torch.zeros((*env.batch_size, 1), dtype=torch.bool)
    mask.view(-1)[0] = True  # the first env only
    return mask


def _lockstep(original: EnvBase, twin: EnvBase, root: TensorDictBase, steps: int = 5) -> None:
    """Step, partially reset, step and reset both envs alike; every output must be identical."""
    roots = [root, root.clone()]
    envs = [original, twin]
    actions = _actions(original, 2 * steps)
    for phase in ("before the partial reset", "after the partial reset"):
        for t in range(steps):
            action = actions[t if phase.startswith("before") else steps + t]
            outs = [env.step(r.clone().set("action", action)) for env, r in zip(envs, roots, strict=True)]
            _assert_same(outs[0], outs[1], f"step {t} {phase}")
            roots = [env.step_mdp(out) for env, out in zip(envs, outs, strict=True)]
        if phase.startswith("before"):
            mask = _reset_mask(original)
            roots = [env.reset(r.clone().set("_reset", mask)) for env, r in zip(envs, roots, strict=True)]
            _assert_same(roots[0], roots[1], "partial reset")
    _assert_same(original.reset(), twin.reset(), "full reset")  # the generators were copied too


def _started(make: Callable[[], EnvBase]) -> tuple[EnvBase, TensorDictBase]:
    """An env a few steps into its episodes, and its current root tensordict."""
    env = make()
    root = env.reset()
    for action in _actions(env, 3):
        root = env.step_mdp(env.step(root.set("action", action)))
    return env, root


# ------------------------------------------------------------------------------ coverage
def test_every_env_class_of_torchtasks_envs_is_covered() -> None:
    names = set()
    for name in torchtasks.envs.__all__:
        try:
            value = getattr(torchtasks.envs, name)
        except ImportError:  # a name of the mujoco extra without it installed
            assert name in {"BatchedMujocoEnv", "ZeroBrokenStepReward"} or not HAS_MUJOCO, name
            continue
        if isinstance(value, type) and issubclass(value, EnvBase):
            names.add(name)
    covered = {param.values[0] for param in ENVS}
    assert names <= covered, f"env classes without round-trip tests: {sorted(names - covered)}"
    if HAS_MUJOCO:
        assert names == covered


# ------------------------------------------------------------------------ copies and pickles
@pytest.mark.parametrize("round_trip", list(ROUND_TRIPS))
@pytest.mark.parametrize(("name", "make"), ENVS)
def test_a_copy_continues_the_same_trajectories(name: str, make: Callable[[], EnvBase], round_trip: str) -> None:
    env, root = _started(make)
    twin = ROUND_TRIPS[round_trip](env)
    assert type(twin) is type(env) and twin.batch_size == env.batch_size and twin.device == env.device
    try:
        _lockstep(env, twin, root)
    finally:
        env.close()
        twin.close()


@pytest.mark.parametrize("round_trip", list(ROUND_TRIPS))
@pytest.mark.parametrize(("name", "make"), ENVS)
def test_a_copy_is_independent_of_the_original(name: str, make: Callable[[], EnvBase], round_trip: str) -> None:
    """Stepping, reseeding or closing one of them leaves the other as it was."""
    env, root = _started(make)
    twin = ROUND_TRIPS[round_trip](env)
    reference = ROUND_TRIPS[round_trip](env)  # what the twin must still do after the original moved on
    for action in _actions(env, 3):
        env.step(root.clone().set("action", action))
    env.set_seed(123)
    env.close()
    try:
        _lockstep(twin, reference, root)
    finally:
        twin.close()
        reference.close()


@pytest.mark.skipif(not HAS_MUJOCO, reason="needs the mujoco extra (mujoco, gymnasium)")
@pytest.mark.mujoco
def test_a_batched_copy_has_its_own_threads_and_simulation() -> None:
    from torchtasks.envs import BatchedMujocoEnv

    env = BatchedMujocoEnv("Hopper-v5", 4, seed=0, num_threads=2)
    env.reset()
    for twin in (copy.deepcopy(env), pickle.loads(pickle.dumps(env))):
        assert twin.num_threads == 2 and twin.batch.nthread == 2 and twin.batch is not env.batch
        assert twin.model is not env.model
        assert not np.shares_memory(twin.batch.state, env.batch.state)
        # the readings read the copy's own state rows and buffers (views of them, not copies)
        assert all(
            np.shares_memory(source, twin.batch.state)
            or any(np.shares_memory(source, buffer) for buffer, _ in twin._readers)
            for source in twin._arrays.values()
        )
        twin.close()
    env.close()


@pytest.mark.skipif(not HAS_MUJOCO, reason="needs the mujoco extra (mujoco, gymnasium)")
@pytest.mark.mujoco
def test_the_batched_preset_can_be_copied() -> None:
    """``gymnasium_env``'s stack (task transform, broken-step transform, RewardSum) round-trips with its env."""
    from torchtasks.envs.locomotion import gymnasium_env

    env = gymnasium_env("Walker2d-v5", num_envs=3, seed=0, num_threads=2)
    root = env.reset()
    for action in _actions(env, 3):
        root = env.step_and_maybe_reset(root.set("action", action))[1]
    for round_trip in ROUND_TRIPS.values():
        twin = round_trip(env)
        roots = [root.clone(), root.clone()]
        for t, action in enumerate(_actions(env, 20)):
            pairs = [e.step_and_maybe_reset(r.set("action", action)) for e, r in zip((env, twin), roots, strict=True)]
            _assert_same(pairs[0][0], pairs[1][0], f"step {t}")
            roots = [pair[1] for pair in pairs]
        root = roots[0]
        twin.close()
    env.close()


# ----------------------------------------------------------------------------- closed envs
@pytest.mark.skipif(not HAS_MUJOCO, reason="needs the mujoco extra (mujoco, gymnasium)")
@pytest.mark.mujoco
def test_a_closed_batched_env_refuses_to_step_or_reset() -> None:
    """Before, a closed env stepped on silently with one thread."""
    from torchtasks.envs import BatchedMujocoEnv

    env = BatchedMujocoEnv("Swimmer-v5", 4, seed=0, num_threads=2)
    root = env.reset()
    twin = copy.deepcopy(env)
    env.close()
    env.close()  # closing twice is allowed
    action = torch.zeros(4, 2)
    with pytest.raises(RuntimeError, match="closed"):
        env.step(root.clone().set("action", action))
    with pytest.raises(RuntimeError, match="closed"):
        env.reset()
    with pytest.raises(RuntimeError, match="closed"):
        env.rollout(2)
    with pytest.raises(RuntimeError, match="closed"):  # a copy of a closed env is closed too
        copy.deepcopy(env).reset()
    # the copy taken before closing is its own env and still runs
    assert twin.rollout(3)["next", "observation"].shape == (4, 3, 8)
    twin.close()


# ---------------------------------------------------------------------------------- devices
def _leaves_on(tensordict: TensorDictBase, device: torch.device) -> None:
    assert tensordict.device == device
    for key, value in tensordict.items(True, True):
        assert value.device == device, f"{key} is on {value.device}, the env on {device}"


@pytest.mark.parametrize(("name", "make"), ENVS)
def test_to_moves_the_outputs_of_the_next_steps(
    name: str, make: Callable[[], EnvBase], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``EnvBase.to`` sets the env's device; the outputs of the next reset and step must be there.

    ``meta`` stands for any other device (TorchRL cannot move a bounded action spec to ``meta``, so the
    spec move is stubbed out; the device change is ``EnvBase.to``'s own). The batched MuJoCo env used to
    choose its numpy->torch conversion once, at construction, and kept writing CPU tensors.
    """
    env = make()
    root = env.reset()
    meta = torch.device("meta")
    with monkeypatch.context() as patch:
        patch.setattr(Composite, "to", lambda self, dest: self)
        assert env.to(meta) is env
    assert env.device == meta
    reset = env._reset(None)
    _leaves_on(reset, meta)
    if name == "BatchedMujocoEnv":  # simulated on the CPU: it reads the action's values (a policy's, on any device)
        step_input = TensorDict({"action": torch.zeros(env.action_spec.shape)}, env.batch_size)
    else:  # torch envs compute on the device of their state
        step_input = reset.clone().set("action", torch.zeros(env.action_spec.shape, device=meta))
    _leaves_on(env._step(step_input), meta)
    # and back: the full TorchRL loop on the CPU again
    with monkeypatch.context() as patch:
        patch.setattr(Composite, "to", lambda self, dest: self)
        env.to("cpu")
    cpu = torch.device("cpu")
    rollout = env.rollout(3, tensordict=root.to(cpu), auto_reset=False)
    _leaves_on(rollout, cpu)
    env.close()


@pytest.mark.parametrize(("name", "make"), ENVS)
def test_to_round_trip_on_the_cpu(name: str, make: Callable[[], EnvBase]) -> None:
    """An env without a device, moved to the CPU, keeps working and writes CPU tensors; a copy keeps the device."""
    env = make()
    env.to("cpu")
    cpu = torch.device("cpu")
    assert env.device == cpu and env.observation_spec.device == cpu
    _leaves_on(env.rollout(3), cpu)
    twin = copy.deepcopy(env)
    assert twin.device == cpu
    _leaves_on(twin.rollout(2), cpu)
    env.close()
    twin.close()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU")
@pytest.mark.parametrize(("name", "make"), ENVS)
def test_to_round_trip_on_a_gpu(name: str, make: Callable[[], EnvBase]) -> None:
    env = make()
    cuda = torch.device("cuda", torch.cuda.current_device())
    env.to(cuda)
    _leaves_on(env.rollout(3), cuda)
    _leaves_on(pickle.loads(pickle.dumps(env)).rollout(2), cuda)
    env.to("cpu")
    _leaves_on(env.rollout(3), torch.device("cpu"))
    env.close()


# --------------------------------------------------------------------- the envs' argument checks
@pytest.mark.parametrize("value", [1, 7, np.int64(2), np.int32(3), np.uint8(4)])
def test_check_positive_int_accepts_python_and_numpy_integers(value: Any) -> None:
    result = check_positive_int(value, "num_envs")
    assert result == int(value) and type(result) is int


@pytest.mark.parametrize(
    ("value", "error"),
    [
        (True, TypeError),
        (np.bool_(True), TypeError),
        (2.0, TypeError),
        (np.float64(2.0), TypeError),
        ("2", TypeError),
        (None, TypeError),
        (0, ValueError),
        (-3, ValueError),
        (np.int64(0), ValueError),
    ],
)
def test_check_positive_int_rejects_by_name(value: Any, error: type[Exception]) -> None:
    with pytest.raises(error, match="num_envs must be a positive int, got "):
        check_positive_int(value, "num_envs")
