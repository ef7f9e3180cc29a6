"""BatchedMujocoEnv on models no one here wrote: trajectories and every reading bit for bit, resets, run state.

The reference of each env is its own ``mujoco.MjData`` on its own ``MjModel`` copy (the env's per-env physics set by
hand: ``reference_model`` of test_batched_mujoco_domain.py), built here from the model file with one
acceleration-stage sensor added (test_readings' ``_with_contact_sensor``: MuJoCo then fills ``cfrc_ext`` in every
forward pass; a sensor changes no dynamics). A step writes ``ctrl = offset + scale * action`` (offset and scale
computed here from the ``Actions`` given) and calls ``mj_step`` ``frame_skip`` times; for ``stage="velocity"`` it then
calls ``mj_step1``, which is what the batch's ``mjSTAGE_VEL`` step is: the position- and velocity-stage fields are of
the returned state, the acceleration-stage ones (actuator forces, accelerometers, touch, ``cfrc_ext``) those of the
last substep's forward pass. For ``stage="step"`` nothing follows ``mj_step``: every derived field is of the last
substep's forward pass, the state (``qpos``, ``qvel``, ``time``) the returned one. A reset is ``mj_resetData`` (or
``mj_resetDataKeyframe``), the declared draws from per-env generators made here by their definition
(``SeedSequence(seed).spawn(num_envs)``, ``PCG64``, draws in the declared order: ``qpos_noise``, ``qvel_noise``,
``joint_noise`` in order, the free joint's position, yaw, linear and angular velocity) and ``mj_forward``.

Every reading kind on every named object of the model (test_readings' ``_cases``) is then compared with MuJoCo's
own function on (a copy of) the reference ``MjData`` in the same state, bit for bit; ``contact_force`` with the
``cfrc_ext`` MuJoCo's ``mj_rnePostConstraint`` wrote in that forward pass. Finite differences are compared with
``(value now - value at the previous step or reset) / dt`` of the reference.
"""

from __future__ import annotations

import copy
import pickle
import re
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")
pytest.importorskip("gymnasium")

import torch  # noqa: E402
from tensordict import TensorDict  # noqa: E402

from model_files import dm_control_suite_xml, gymnasium_asset  # noqa: E402
from test_batched_mujoco_domain import reference_model  # noqa: E402
from test_readings import _cases, _spec, _with_contact_sensor  # noqa: E402
from torchtasks.envs import BatchedMujocoEnv  # noqa: E402
from torchtasks.envs import readings as R  # noqa: E402
from torchtasks.envs.models import model_path  # noqa: E402
from torchtasks.envs.mujoco_declaration import Actions, FreeJointRanges, Noise, Resets  # noqa: E402

pytestmark = [
    pytest.mark.mujoco,
    # MuJoCo 4 about dm_control's cheetah.xml (a file no one here wrote), when the env or the test compiles it
    pytest.mark.filterwarnings("ignore:compiler attribute 'settotalmass' is deprecated:UserWarning"),
]

NUM_ENVS = 4
STEPS = 24
#: the step before which envs RESET_MASK are reset, and the one before which MID_MASK get new physics mid-episode
PARTIAL_RESET, MID_EPISODE = 9, 16
RESET_MASK = [False, True, False, True]
MID_MASK = [True, False, False, True]
#: env 3 keeps the nominal physics until MID_EPISODE
FIRST_MASK = [True, True, True, False]
#: the steps after which every reading is compared (qpos, qvel and the finite differences after every step)
READING_CHECKS = {0, 1, PARTIAL_RESET, MID_EPISODE, STEPS - 1}

_SHIPPED_RESETS = Resets(
    keyframe="home",
    joint_noise={"FL_calf_joint": Noise("uniform", 0.1), "RR_thigh_joint": Noise("normal", 0.05, mode="scale")},
    qvel_noise=Noise("uniform", 0.2),
    free_joint=FreeJointRanges(
        position=((-0.5, 0.5), (-0.5, 0.5), (0.0, 0.02)),
        yaw=(-3.14, 3.14),
        linear_velocity=((-0.2, 0.2), (-0.2, 0.2), (0.0, 0.0)),
        angular_velocity=((-0.3, 0.3), (-0.3, 0.3), (-0.3, 0.3)),
    ),
)


@dataclass(frozen=True)
class Case:
    """A model and a declaration of it (the readings are every kind on every named object, added by the test)."""

    source: Callable[[], Path]
    stage: str
    frame_skip: int
    resets: Resets
    actions: Actions | None = None
    seed: int = 7


CASES: dict[str, Case] = {
    "dm_control quadruped": Case(
        lambda: dm_control_suite_xml("quadruped.xml"),
        "velocity",
        4,
        Resets(qpos_noise=Noise("uniform", 0.05), qvel_noise=Noise("normal", 0.3)),
    ),
    "dm_control humanoid": Case(
        lambda: dm_control_suite_xml("humanoid.xml"),
        "step",
        3,
        Resets(
            joint_noise={"right_knee": Noise("uniform", 0.3), "left_hip_y": Noise("normal", 0.1)},
            free_joint=FreeJointRanges(position=((-0.1, 0.1), (-0.1, 0.1), (0.0, 0.05)), yaw=(-1.0, 1.0)),
        ),
        Actions(scale=0.8),
    ),
    "dm_control walker": Case(
        lambda: dm_control_suite_xml("walker.xml"),
        "velocity",
        5,
        Resets(qpos_noise=Noise("normal", 0.05, mode="scale"), qvel_noise=Noise("uniform", 0.1, mode="add")),
        Actions(scale=[0.5, 0.6, 0.7, 0.8, 0.9, 1.0], offset=[0.1, -0.1, 0.0, 0.2, 0.0, -0.2]),
    ),
    "dm_control cheetah": Case(
        lambda: dm_control_suite_xml("cheetah.xml"), "step", 2, Resets(qpos_noise=Noise("uniform", 0.1))
    ),
    "gymnasium ant": Case(
        lambda: gymnasium_asset("ant.xml"),
        "velocity",
        5,
        Resets(qpos_noise=Noise("uniform", 0.1), qvel_noise=Noise("normal", 0.1)),
    ),
    "shipped quadruped (step)": Case(
        lambda: model_path("quadruped"), "step", 4, _SHIPPED_RESETS, Actions(scale=0.3, offset="home")
    ),
    "shipped quadruped (velocity)": Case(
        lambda: model_path("quadruped"), "velocity", 4, _SHIPPED_RESETS, Actions(scale=0.3, offset="home")
    ),
}


# ------------------------------------------------------------------------------ the reference
def generators(seed: int, n: int) -> list[np.random.Generator]:
    """Each env's reset generator, by the env's definition: PCG64 of the n children of SeedSequence(seed)."""
    return [np.random.Generator(np.random.PCG64(child)) for child in np.random.SeedSequence(seed).spawn(n)]


def affine(model: mujoco.MjModel, actions: Actions | None) -> tuple[np.ndarray, np.ndarray]:
    """``(offset, scale)`` per actuator of ``Actions``: a pose's offset is the actuator's joint position in it."""
    actions = Actions() if actions is None else actions
    scale = np.broadcast_to(np.asarray(actions.scale, dtype=np.float64), (model.nu,)).copy()
    if isinstance(actions.offset, str):
        pose = model.qpos0 if actions.offset == "qpos0" else model.key(actions.offset).qpos
        joints = model.actuator_trnid[:, 0]
        return pose[model.jnt_qposadr[joints]].copy(), scale
    return np.broadcast_to(np.asarray(actions.offset, dtype=np.float64), (model.nu,)).copy(), scale


def draw_reset(model: mujoco.MjModel, data: mujoco.MjData, resets: Resets, rng: np.random.Generator) -> None:
    """Reset ``data`` as the declaration says, drawing from ``rng`` (then mj_forward)."""
    if resets.keyframe is None:
        mujoco.mj_resetData(model, data)
    else:
        mujoco.mj_resetDataKeyframe(model, data, model.key(resets.keyframe).id)
    noises = []
    if resets.qpos_noise is not None:
        noises.append((data.qpos, np.arange(model.nq), resets.qpos_noise))
    if resets.qvel_noise is not None:
        noises.append((data.qvel, np.arange(model.nv), resets.qvel_noise))
    for name, noise in resets.joint_noise.items():
        noises.append((data.qpos, np.array([model.joint(name).qposadr[0]]), noise))
    for array, columns, noise in noises:
        if noise.distribution == "uniform":
            draw = rng.uniform(-noise.scale, noise.scale, size=columns.size)
        else:
            draw = noise.scale * rng.standard_normal(columns.size)
        array[columns] = array[columns] + draw if noise.mode == "add" else array[columns] * (1.0 + draw)
    ranges = resets.free_joint
    if ranges is not None:
        joint = model.joint(ranges.joint) if ranges.joint else model.joint(int(np.flatnonzero(model.jnt_type == 0)[0]))
        q, v = int(joint.qposadr[0]), int(joint.dofadr[0])
        if ranges.position is not None:
            low, high = np.array(ranges.position).T
            data.qpos[q : q + 3] += rng.uniform(low, high)
        if ranges.yaw is not None:
            yaw = rng.uniform(*ranges.yaw)
            turned = np.zeros(4)
            mujoco.mju_mulQuat(turned, np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]), data.qpos[q + 3 : q + 7])
            data.qpos[q + 3 : q + 7] = turned
        for pairs, columns in ((ranges.linear_velocity, slice(v, v + 3)), (ranges.angular_velocity, slice(v + 3, v + 6))):
            if pairs is not None:
                low, high = np.array(pairs).T
                data.qvel[columns] += rng.uniform(low, high)
    mujoco.mj_forward(model, data)


@dataclass
class Twin:
    """The reference envs of one batched env: per-env models, data, generators, last actions and differences."""

    case: Case
    nominal: mujoco.MjModel
    #: the model as the file declares it (its objects' names are what the readings read)
    model: mujoco.MjModel
    models: list[mujoco.MjModel] = field(default_factory=list)
    datas: list[mujoco.MjData] = field(default_factory=list)
    values: list[dict[str, np.ndarray]] = field(default_factory=list)
    rngs: list[np.random.Generator] = field(default_factory=list)
    #: the last action of each env (``_cases``' last_action references read it)
    actions: np.ndarray = field(default_factory=lambda: np.zeros(0))
    previous: dict[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def of(cls, case: Case) -> Twin:
        nominal = _with_contact_sensor(_spec(case.source()))
        twin = cls(case, nominal, _spec(case.source()).compile())
        twin.values = [{} for _ in range(NUM_ENVS)]
        twin.models = [reference_model(nominal, {}) for _ in range(NUM_ENVS)]
        twin.datas = [mujoco.MjData(model) for model in twin.models]
        twin.rngs = generators(case.seed, NUM_ENVS)
        twin.actions = np.zeros((NUM_ENVS, nominal.nu))
        twin.offset, twin.scale = affine(nominal, case.actions)
        return twin

    def set(self, values: dict[str, torch.Tensor], mask: list[bool]) -> None:
        for i in np.flatnonzero(mask).tolist():
            self.values[i].update({name: value[i].numpy() for name, value in values.items()})
            self.models[i] = reference_model(self.nominal, self.values[i])

    def reset(self, ids: list[int]) -> None:
        for i in ids:
            draw_reset(self.models[i], self.datas[i], self.case.resets, self.rngs[i])
            self.actions[i] = 0.0

    def step(self, action: np.ndarray) -> None:
        for i, (model, data) in enumerate(zip(self.models, self.datas, strict=True)):
            data.ctrl[:] = self.offset + self.scale * action[i]
            for _ in range(self.case.frame_skip):
                mujoco.mj_step(model, data)
            if self.case.stage == "velocity":
                mujoco.mj_step1(model, data)
        self.actions = action.copy()


def differenced(twin: Twin) -> dict[str, np.ndarray]:
    """The values the test's finite differences difference (``[num_envs, size]``), from the reference data."""
    root = 1
    hinge = int(np.flatnonzero(twin.nominal.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)[0])
    adr = twin.nominal.jnt_qposadr[hinge]
    return {
        "com_rate": np.stack([data.subtree_com[root].copy() for data in twin.datas]),
        "hinge_rate": np.stack([data.qpos[[adr]].copy() for data in twin.datas]),
    }


def state_readings(model: mujoco.MjModel) -> dict[str, R.Reading]:
    hinge = int(np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)[0])
    return {
        "qpos": R.joint_pos(),
        "qvel": R.joint_vel(),
        "com_rate": R.finite_difference(R.subtree_com(model.body(1).name)),
        "hinge_rate": R.finite_difference(R.joint_pos(model.joint(hinge).name), dt=0.05),
    }


def domain_names(model: mujoco.MjModel) -> list[str]:
    """A body's mass, a geom's friction and gravity: the root body, the first named geom."""
    geom = next(model.geom(g).name for g in range(model.ngeom) if model.geom(g).name)
    return [f"body_mass:{model.body(1).name}", f"geom_friction:{geom}", "gravity"]


def draw_domain(env: BatchedMujocoEnv, names: list[str], rng: np.random.Generator) -> dict[str, torch.Tensor]:
    values = {}
    for each in env.domain_fields(names):
        nominal = each.nominal.numpy()
        shape = (NUM_ENVS, *each.value_shape)
        change = rng.uniform(-2.0, 2.0, shape) if each.name == "gravity" else rng.uniform(0.6, 1.4, shape)
        values[each.name] = torch.from_numpy(nominal + change if each.name == "gravity" else nominal * change)
    return values


@dataclass
class Comparison:
    """The readings of the env (``r<k>`` entries) and MuJoCo's function for each."""

    readings: dict[str, R.Reading]
    references: dict[str, Callable[[Any, Any, int], np.ndarray]]


def every_reading(twin: Twin) -> Comparison:
    """Every kind on every named object (test_readings' cases); contact forces: MuJoCo's cfrc_ext of the pass."""
    readings, references = {}, {}
    for k, (reading, reference) in enumerate(_cases(twin)):
        if reading.kind == "contact_force":
            bodies = [twin.nominal.body(name).id for name in reading.bodies] or list(range(1, twin.nominal.nbody))

            def reference(m: Any, d: Any, i: int, bodies: list[int] = bodies) -> np.ndarray:
                return d.cfrc_ext[bodies].ravel()

        readings[f"r{k}"], references[f"r{k}"] = reading, reference
    return Comparison(readings, references)


def assert_state(env: BatchedMujocoEnv, twin: Twin, out: TensorDict, context: str, rows: list[int]) -> None:
    for i in rows:
        np.testing.assert_array_equal(out["qpos"][i].numpy(), twin.datas[i].qpos, err_msg=f"{context} env {i}")
        np.testing.assert_array_equal(out["qvel"][i].numpy(), twin.datas[i].qvel, err_msg=f"{context} env {i}")


def assert_readings(comparison: Comparison, twin: Twin, out: TensorDict, context: str, rows: list[int]) -> None:
    checked = 0
    for i in rows:
        model, data = twin.models[i], copy.copy(twin.datas[i])  # a copy: some references write (mj_subtreeVel)
        for key, reference in comparison.references.items():
            expected = np.asarray(reference(model, data, i), dtype=np.float64).ravel()
            np.testing.assert_array_equal(
                out[key][i].numpy(), expected, err_msg=f"{context} env {i}: {comparison.readings[key]}"
            )
            checked += 1
    assert checked == len(rows) * len(comparison.readings)


def assert_differences(twin: Twin, out: TensorDict, dt: float, context: str, reset: list[int]) -> None:
    """The finite differences: 0 in the envs just reset, else (now - previous) / dt; then remember now."""
    now = differenced(twin)
    for key, value in now.items():
        step = dt if key == "com_rate" else 0.05
        expected = (value - twin.previous[key]) / step
        expected[reset] = 0.0
        np.testing.assert_array_equal(out[key].numpy(), expected, err_msg=f"{context} {key}")
        twin.previous[key] = value


@pytest.mark.parametrize("name", list(CASES))
def test_trajectories_and_every_reading_equal_per_env_mjdata_bit_for_bit(name: str) -> None:
    case = CASES[name]
    twin = Twin.of(case)
    comparison = every_reading(twin)
    env = BatchedMujocoEnv(
        case.source(),
        NUM_ENVS,
        observation=comparison.readings,
        state=state_readings(twin.nominal),
        actions=case.actions,
        resets=case.resets,
        frame_skip=case.frame_skip,
        stage=case.stage,
        seed=case.seed,
        num_threads=2,
    )
    assert env.model.nq == twin.nominal.nq and env.dt == case.frame_skip * twin.nominal.opt.timestep
    rng = np.random.default_rng(0)
    names = domain_names(twin.nominal)
    first = draw_domain(env, names, rng)
    env.set_domain(first, torch.tensor(FIRST_MASK))
    twin.set(first, FIRST_MASK)
    everyone = list(range(NUM_ENVS))
    out = env.reset()
    twin.reset(everyone)
    twin.previous = differenced(twin)
    assert_state(env, twin, out, f"{name} reset", everyone)
    assert_readings(comparison, twin, out, f"{name} reset", everyone)
    low, high = env.action_spec.space.low[0].numpy(), env.action_spec.space.high[0].numpy()
    for step in range(STEPS):
        reset: list[int] = []
        if step == PARTIAL_RESET:
            out = env.reset(TensorDict({"_reset": torch.tensor(RESET_MASK)[:, None]}, [NUM_ENVS]))
            reset = np.flatnonzero(RESET_MASK).tolist()
            twin.reset(reset)
            now = differenced(twin)
            for key in now:
                twin.previous[key][reset] = now[key][reset]
            assert_state(env, twin, out, f"{name} partial reset", reset)
            assert_readings(comparison, twin, out, f"{name} partial reset", reset)
        if step == MID_EPISODE:
            values = draw_domain(env, names, rng)
            env.set_domain(values, torch.tensor(MID_MASK))
            twin.set(values, MID_MASK)
        action = torch.from_numpy(rng.uniform(low, high, size=(NUM_ENVS, env.model.nu)).astype(np.float32))
        out = env.step(TensorDict({"action": action}, [NUM_ENVS]))["next"]
        twin.step(action.double().numpy())
        context = f"{name} step {step}"
        assert_state(env, twin, out, context, everyone)
        assert_differences(twin, out, env.dt, context, [])
        if step in READING_CHECKS:
            assert_readings(comparison, twin, out, context, everyone)
    assert not out["broken"].any()
    env.close()
