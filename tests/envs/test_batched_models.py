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
``(value now - value at the previous step or reset) / dt`` of the reference, a composite reading's among them.
"""

from __future__ import annotations

import copy
import pickle
import re
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
from test_batched_mujoco_domain import reference_model  # noqa: E402
from test_readings import _cases, _in_frame, _norm3, _spec, _with_contact_sensor  # noqa: E402

from model_files import dm_control_suite_xml, gymnasium_asset  # noqa: E402
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
        for pairs, columns in (
            (ranges.linear_velocity, slice(v, v + 3)),
            (ranges.angular_velocity, slice(v + 3, v + 6)),
        ):
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
        "gap_rate": np.stack(
            [[_norm3(_in_frame(data.xmat[root], data.xpos[root] - data.subtree_com[root]))] for data in twin.datas]
        ),
    }


def state_readings(model: mujoco.MjModel) -> dict[str, R.Reading]:
    hinge = int(np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)[0])
    root = model.body(1).name
    return {
        "qpos": R.joint_pos(),
        "qvel": R.joint_vel(),
        "com_rate": R.finite_difference(R.subtree_com(root)),
        "hinge_rate": R.finite_difference(R.joint_pos(model.joint(hinge).name), dt=0.05),
        # a composite reading's finite difference: the root's distance from its subtree's centre of mass
        "gap_rate": R.finite_difference(
            R.norm(R.difference(R.body_pos(root), R.subtree_com(root), frame=f"body:{root}")), dt=0.05
        ),
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


# ------------------------------------------------------------------------------ resets
def _mask(*rows: int, n: int = NUM_ENVS) -> torch.Tensor:
    mask = torch.zeros(n, 1, dtype=torch.bool)
    mask[list(rows)] = True
    return mask


def _running(env: BatchedMujocoEnv) -> dict[str, Any]:
    """The env's running episodes (every simulation's mjSTATE_INTEGRATION row, buffers, last actions), copied."""
    return copy.deepcopy(env.state_dict()["_extra_state"]["running_episodes"])


def _assert_rows_equal(before: dict[str, Any], after: dict[str, Any], rows: list[int]) -> None:
    """The running episodes of envs ``rows`` are the same in both (every per-env tensor, row by row)."""
    for key in ("integration_state", "warnings", "time", "previous_position", "last_action"):
        torch.testing.assert_close(after[key][rows], before[key][rows], rtol=0, atol=0, msg=key)
    for k, (a, b) in enumerate(zip(after["gathered"], before["gathered"], strict=True)):
        torch.testing.assert_close(a[rows], b[rows], rtol=0, atol=0, msg=f"gathered[{k}]")


def test_a_keyframe_start_is_the_keyframe_and_partial_resets_leave_the_others_untouched() -> None:
    model = mujoco.MjModel.from_xml_path(str(model_path("quadruped")))
    key = model.key("home")
    env = BatchedMujocoEnv(
        model_path("quadruped"),
        NUM_ENVS,
        observation={"qpos": R.joint_pos(), "qvel": R.joint_vel(), "ctrl": R.actuator_ctrl()},
        state={"speed": R.finite_difference(R.body_pos("torso")), "action": R.last_action()},
        resets=Resets(keyframe="home", qvel_noise=Noise("uniform", 0.1)),
        frame_skip=4,
        seed=1,
    )
    out = env.reset()
    for i in range(NUM_ENVS):
        np.testing.assert_array_equal(out["qpos"][i].numpy(), key.qpos)
        np.testing.assert_array_equal(out["ctrl"][i].numpy(), key.ctrl)
    assert (out["qvel"] != 0).all() and (out["qvel"] - torch.from_numpy(key.qvel)).abs().max() <= 0.1
    for _ in range(3):
        out = env.step(env.full_action_spec.rand().update(out))["next"]
    before = _running(env)
    after_reset = env.reset(TensorDict({"_reset": _mask(0, 2)}, [NUM_ENVS]))
    after = _running(env)
    _assert_rows_equal(before, after, [1, 3])
    for i in (0, 2):
        np.testing.assert_array_equal(after_reset["qpos"][i].numpy(), key.qpos)
        np.testing.assert_array_equal(after_reset["ctrl"][i].numpy(), key.ctrl)
        assert (after_reset["action"][i] == 0).all() and (after_reset["speed"][i] == 0).all()
        assert after["time"][i] == 0
    assert (after["time"][[1, 3]] > 0).all()
    # an empty mask resets nothing
    env.reset(TensorDict({"_reset": _mask()}, [NUM_ENVS]))
    _assert_rows_equal(after, _running(env), list(range(NUM_ENVS)))
    env.close()


def test_reset_draws_equal_the_generators_definition_and_have_the_declared_moments() -> None:
    """Each distribution and mode on hinge joints, qvel noise and the free joint's ranges, env by env; then moments."""
    n, seed = 600, 11
    joints = {
        "FL_hip_joint": Noise("uniform", 0.2),
        "FR_thigh_joint": Noise("normal", 0.1),
        "RL_calf_joint": Noise("uniform", 0.3, mode="scale"),
        "RR_calf_joint": Noise("normal", 0.05, mode="scale"),
    }
    ranges = FreeJointRanges(
        position=((-1.0, 1.0), (-0.5, 0.5), (0.1, 0.2)),
        yaw=(-3.0, 2.0),
        linear_velocity=((-0.2, 0.2), (0.0, 0.0), (-0.1, 0.3)),
        angular_velocity=((-0.3, 0.3), (-0.1, 0.1), (0.5, 0.6)),
    )
    resets = Resets(keyframe="home", qvel_noise=Noise("normal", 0.5), joint_noise=joints, free_joint=ranges)
    env = BatchedMujocoEnv(
        model_path("quadruped"), n, observation={"qpos": R.joint_pos(), "qvel": R.joint_vel()}, resets=resets, seed=seed
    )
    out = env.reset()
    model = env.model
    reference, data = generators(seed, n), mujoco.MjData(model)
    qpos, qvel = out["qpos"].numpy(), out["qvel"].numpy()
    for i in range(n):
        draw_reset(model, data, resets, reference[i])
        np.testing.assert_array_equal(qpos[i], data.qpos, err_msg=f"env {i}")
        np.testing.assert_array_equal(qvel[i], data.qvel, err_msg=f"env {i}")
    key = model.key("home")
    for name, noise in joints.items():
        adr = model.joint(name).qposadr[0]
        default = key.qpos[adr]
        offset = qpos[:, adr] - default if noise.mode == "add" else qpos[:, adr] / default - 1.0
        std = noise.scale / np.sqrt(3) if noise.distribution == "uniform" else noise.scale
        assert abs(offset.mean()) < 5 * std / np.sqrt(n), name
        assert abs(offset.std() / std - 1) < 0.15, name
        if noise.distribution == "uniform":
            assert np.abs(offset).max() <= noise.scale * (1 + 1e-12), name
    position = qpos[:, :3] - key.qpos[:3]
    for axis, (low, high) in enumerate(ranges.position):
        assert low <= position[:, axis].min() and position[:, axis].max() <= high
        assert abs(position[:, axis].mean() - (low + high) / 2) < 5 * (high - low) / np.sqrt(12 * n)
    # the orientation: the keyframe's rotated about world z by the yaw drawn (key quat is upright: a pure yaw)
    quaternion = qpos[:, 3:7]
    assert np.allclose(key.qpos[3:7], [1, 0, 0, 0])
    np.testing.assert_allclose(quaternion[:, 1:3], 0.0, atol=1e-15)
    yaw = 2 * np.arctan2(quaternion[:, 3], quaternion[:, 0])
    assert -3.0 <= yaw.min() and yaw.max() <= 2.0 and abs(yaw.mean() + 0.5) < 0.15
    velocity = qvel[:, :6] - key.qvel[:6]  # the key's qvel is zero, plus the qvel noise drawn before the ranges
    assert np.abs(velocity).max() > 0.3  # the normal qvel noise is there too
    env.close()


def test_the_yaw_turns_a_tilted_default_about_the_world_z_axis() -> None:
    xml = """<mujoco><worldbody><body name="box" pos="0 0 1" quat="0.9 0.3 0.2 0.1"><freejoint name="root"/>
      <geom type="box" size=".1 .2 .3"/></body></worldbody>
      <actuator><motor joint="root" gear="0 0 1 0 0 0"/></actuator></mujoco>"""
    ranges = FreeJointRanges(yaw=(-3.0, 3.0))
    env = BatchedMujocoEnv(xml, 8, observation=R.body_quat("box"), resets=Resets(free_joint=ranges), seed=3)
    out = env.reset()["observation"].numpy()
    default = env.model.qpos0[3:7]
    for i, rng in enumerate(generators(3, 8)):
        yaw = rng.uniform(-3.0, 3.0)
        turned, other = np.zeros(4), np.zeros(4)
        mujoco.mju_mulQuat(turned, np.array([np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]), default)
        mujoco.mju_mulQuat(other, default, np.array([np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]))
        normalised = turned / np.linalg.norm(turned)
        np.testing.assert_allclose(out[i], normalised, rtol=0, atol=1e-15)
        assert not np.allclose(out[i], other / np.linalg.norm(other))  # not about the body's own z axis
    env.close()


# ------------------------------------------------------------------------------ resets to given states
def _given_env(model: Path | None = None, **kwargs: Any) -> tuple[BatchedMujocoEnv, Twin, Comparison]:
    case = CASES["shipped quadruped (velocity)"]
    twin = Twin.of(case)
    comparison = every_reading(twin)
    env = BatchedMujocoEnv(
        case.source() if model is None else model,
        NUM_ENVS,
        observation=comparison.readings,
        state=state_readings(twin.nominal),
        actions=case.actions,
        resets=case.resets,
        seed=case.seed,
        **{"frame_skip": case.frame_skip, "stage": case.stage, **kwargs},
    )
    return env, twin, comparison


@pytest.fixture(scope="module")
def given_env() -> tuple[BatchedMujocoEnv, Twin, Comparison]:
    env, twin, comparison = _given_env()
    yield env, twin, comparison
    env.close()


def _states(model: mujoco.MjModel, rng: np.random.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """States near the keyframe (a normalised orientation), as a demonstration would give them."""
    qpos = np.tile(model.key("home").qpos, (NUM_ENVS, 1)) + rng.uniform(-0.1, 0.1, (NUM_ENVS, model.nq))
    qpos[:, 3:7] /= np.linalg.norm(qpos[:, 3:7], axis=1, keepdims=True)
    qvel = rng.normal(0.0, 0.5, (NUM_ENVS, model.nv))
    return torch.from_numpy(qpos), torch.from_numpy(qvel)


def test_a_reset_to_given_states_starts_there_with_every_reading_consistent(given_env) -> None:
    env, twin, comparison = given_env
    rng = np.random.default_rng(5)
    out = env.reset()
    twin.rngs = generators(twin.case.seed, NUM_ENVS)
    env.set_seed(twin.case.seed)
    out = env.reset()
    twin.reset(list(range(NUM_ENVS)))
    twin.previous = differenced(twin)
    low, high = env.action_spec.space.low[0].numpy(), env.action_spec.space.high[0].numpy()

    def step() -> TensorDict:
        action = torch.from_numpy(rng.uniform(low, high, (NUM_ENVS, env.model.nu)).astype(np.float32))
        result = env.step(TensorDict({"action": action}, [NUM_ENVS]))["next"]
        twin.step(action.double().numpy())
        assert_differences(twin, result, env.dt, "step", [])
        return result

    for _ in range(3):
        out = step()
    before = _running(env)
    qpos, qvel = _states(env.model, rng)
    qpos[1] = float("nan")  # rows of envs not reset are not read
    reset = [0, 2]
    out = env.reset(TensorDict({"_reset": _mask(*reset), "reset_qpos": qpos, "reset_qvel": qvel}, [NUM_ENVS]))
    _assert_rows_equal(before, _running(env), [1, 3])
    for i in reset:
        model, data = twin.models[i], twin.datas[i]
        mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
        data.qpos[:], data.qvel[:] = qpos[i].numpy(), qvel[i].numpy()
        mujoco.mj_forward(model, data)
        twin.actions[i] = 0.0
        np.testing.assert_array_equal(out["qpos"][i].numpy(), qpos[i].numpy())
        np.testing.assert_array_equal(out["qvel"][i].numpy(), qvel[i].numpy())
    assert_readings(comparison, twin, out, "given states", reset)
    now = differenced(twin)
    for key in now:
        assert (out[key][reset] == 0).all(), key
        twin.previous[key][reset] = now[key][reset]
    for step_index in range(2):
        out = step()  # the finite differences from the given states
        assert_state(env, twin, out, f"after given states {step_index}", list(range(NUM_ENVS)))
        assert_readings(comparison, twin, out, f"after given states {step_index}", list(range(NUM_ENVS)))
    # without reset_qvel: the reset's default velocities (the keyframe's), no draws
    out = env.reset(TensorDict({"_reset": _mask(3), "reset_qpos": qpos}, [NUM_ENVS]))
    np.testing.assert_array_equal(out["qpos"][3].numpy(), qpos[3].numpy())
    np.testing.assert_array_equal(out["qvel"][3].numpy(), env.model.key("home").qvel)


def test_states_queued_for_the_next_reset_start_there_in_a_transformed_env(given_env) -> None:
    """set_reset_states: the way to given starts wherever TorchRL resets (a TransformedEnv passes the base env only
    its reset and state entries, so reset_qpos in env.reset's tensordict would not reach the base env there)."""
    from torchrl.envs import StepCounter, TransformedEnv

    env = given_env[0]
    transformed = TransformedEnv(env, StepCounter())
    root = transformed.reset()
    qpos, qvel = _states(env.model, np.random.default_rng(6))
    env.set_reset_states(qpos, qvel, mask=torch.tensor([False, True, True, False]))
    transformed.step(root.set("action", torch.zeros(NUM_ENVS, env.model.nu)))  # a step is not a reset: it waits
    out = transformed.reset(TensorDict({"_reset": _mask(0, 1)}, [NUM_ENVS]))
    np.testing.assert_array_equal(out["qpos"][1].numpy(), qpos[1].numpy())  # queued: starts there
    np.testing.assert_array_equal(out["qvel"][1].numpy(), qvel[1].numpy())
    assert not torch.equal(out["qpos"][0], qpos[0])  # not queued: drew
    # env 2's state still waits, through a checkpoint, and is consumed by its reset only
    twin = _given_env()[0]
    twin.load_state_dict(env.state_dict())
    for each in (env, twin):
        first = each.reset(TensorDict({"_reset": _mask(2)}, [NUM_ENVS]))
        np.testing.assert_array_equal(first["qpos"][2].numpy(), qpos[2].numpy())
        again = each.reset(TensorDict({"_reset": _mask(2)}, [NUM_ENVS]))
        assert not torch.equal(again["qpos"][2], qpos[2])
    # without qvel: the reset's default velocities (the keyframe's)
    env.set_reset_states(qpos, mask=torch.tensor([False, False, False, True]))
    out = env.reset(TensorDict({"_reset": _mask(3)}, [NUM_ENVS]))
    np.testing.assert_array_equal(out["qvel"][3].numpy(), env.model.key("home").qvel)
    twin.close()


def test_bad_queued_states_are_refused_and_queue_nothing(given_env) -> None:
    env = given_env[0]
    qpos, qvel = _states(env.model, np.random.default_rng(8))
    bad = qpos.clone()
    bad[1, 0] = float("nan")
    cases = [
        (
            (qpos.float(),),
            {},
            r"set_reset_states: qpos must be a float64 tensor of shape \[4, \d+\] \(num_envs, the model.s nq\), "
            r"got torch.float32",
        ),
        (
            (qpos, qvel[:, :2]),
            {},
            r"set_reset_states: qvel must be a float64 tensor of shape .*got torch.float64 \[4, 2\]",
        ),
        ((bad,), {}, r"set_reset_states: qpos must be finite in the rows of the envs in mask"),
        (
            (qpos,),
            {"mask": torch.ones(4)},
            r"mask must be a bool tensor of shape \[4\] \(num_envs\), got torch.float32",
        ),
    ]
    for args, kwargs, match in cases:
        with pytest.raises(ValueError, match=match):
            env.set_reset_states(*args, **kwargs)
        assert np.isnan(env._queued_qpos).all()  # nothing queued
    env.set_reset_states(bad, mask=torch.tensor([True, False, True, True]))  # rows outside mask are not read
    env.set_reset_states(qpos, mask=torch.zeros(4, dtype=torch.bool))
    env.reset()  # consumes what was queued


def test_bad_given_states_are_refused_and_change_nothing(given_env) -> None:
    env = given_env[0]
    env.reset()
    qpos, qvel = _states(env.model, np.random.default_rng(7))
    nq, nv = env.model.nq, env.model.nv
    bad_row = qvel.clone()
    bad_row[2, 4] = float("inf")
    cases = [
        (
            {"reset_qpos": qpos.float()},
            rf"reset_qpos must be a float64 tensor of shape \[4, {nq}\] \(num_envs, the model's nq\), got "
            rf"torch.float32 \[4, {nq}\]",
        ),
        ({"reset_qpos": qpos[:, :-1]}, rf"reset_qpos must be a float64 tensor of shape \[4, {nq}\] .*\[4, {nq - 1}\]"),
        ({"reset_qpos": qpos, "reset_qvel": qvel[:, None]}, rf"reset_qvel .*\[4, {nv}\] .*got torch.float64 \[4, 1, "),
        ({"reset_qpos": qpos, "reset_qvel": bad_row}, r"reset_qvel must be finite in the rows of the envs reset"),
    ]
    for entries, match in cases:
        before = _running(env)
        with pytest.raises(ValueError, match=match):
            env.reset(TensorDict({"_reset": _mask(1, 2), **entries}, [NUM_ENVS]))
        _assert_rows_equal(before, _running(env), list(range(NUM_ENVS)))


# ------------------------------------------------------------------------------ run state
def _actions(env: BatchedMujocoEnv, steps: int, seed: int) -> list[torch.Tensor]:
    rng = np.random.default_rng(seed)
    low, high = env.action_spec.space.low[0].numpy(), env.action_spec.space.high[0].numpy()
    return [torch.from_numpy(rng.uniform(low, high, (NUM_ENVS, env.model.nu)).astype(np.float32)) for _ in range(steps)]


def _run(env: BatchedMujocoEnv, actions: list[torch.Tensor], reset_at: int | None = None) -> list[TensorDict]:
    """Step ``env`` through ``actions`` (a partial reset of envs 1 and 2 before step ``reset_at``): the outputs."""
    outs = []
    for k, action in enumerate(actions):
        if k == reset_at:
            outs.append(env.reset(TensorDict({"_reset": _mask(1, 2)}, [NUM_ENVS])))
        outs.append(env.step(TensorDict({"action": action}, [NUM_ENVS]))["next"])
    return outs


def _assert_same_outputs(a: list[TensorDict], b: list[TensorDict]) -> None:
    assert len(a) == len(b)
    for k, (x, y) in enumerate(zip(a, b, strict=True)):
        assert set(x.keys()) == set(y.keys())
        for key in x.keys():
            torch.testing.assert_close(x[key], y[key], rtol=0, atol=0, msg=f"output {k} {key}")


def test_a_loaded_state_dict_continues_bit_for_bit_and_another_declaration_refuses_it(
    given_env, tmp_path: Path
) -> None:
    env = given_env[0]
    env.set_seed(3)
    env.set_domain(
        {"gravity": torch.tensor([[0.0, 0.0, -9.0]] * NUM_ENVS, dtype=torch.float64)}, torch.tensor(MID_MASK)
    )
    env.reset()
    _run(env, _actions(env, 4, 0))
    saved = copy.deepcopy(env.state_dict())
    # the same declaration on the same model read from another place (a copy of the file: another checkout)
    moved = tmp_path / "moved_quadruped.xml"
    moved.write_text(model_path("quadruped").read_text())
    fresh = _given_env(model=moved, num_threads=1)[0]
    fresh.set_seed(99)
    fresh.reset()
    fresh.load_state_dict(saved)
    actions = _actions(env, 8, 1)  # the partial reset draws from the restored generators
    _assert_same_outputs(_run(fresh, actions, reset_at=3), _run(env, actions, reset_at=3))
    fresh.close()
    others = {
        "another model": (
            lambda: BatchedMujocoEnv(model_path("arm"), NUM_ENVS, observation=R.joint_pos()),
            r"the saved running episodes are of another simulation \(declaration, frame_skip, model_sha256 differ\)",
        ),
        "another frame_skip": (
            lambda: _given_env(frame_skip=None, control_timestep=0.01)[0],
            r"the saved running episodes are of another simulation \(frame_skip differ\)",
        ),
        "other readings": (
            lambda: BatchedMujocoEnv(
                model_path("quadruped"),
                NUM_ENVS,
                observation=R.joint_pos(),
                resets=Resets(keyframe="home"),
                frame_skip=4,
            ),
            r"the saved running episodes are of another simulation \(declaration differ\)",
        ),
        "another stage": (
            lambda: _given_env(stage="step")[0],  # the case's is "velocity"
            r"the saved running episodes are of another simulation \(declaration differ\)",
        ),
    }
    for label, (make, match) in others.items():
        other = make()
        other.reset()
        _run(other, _actions(other, 2, 2))
        before = copy.deepcopy(other.state_dict())
        with pytest.raises(ValueError, match=match):
            other.load_state_dict(saved)
        after = other.state_dict()
        _assert_rows_equal(
            before["_extra_state"]["running_episodes"], after["_extra_state"]["running_episodes"], list(range(NUM_ENVS))
        )
        assert before["_extra_state"]["bit_generators"] == after["_extra_state"]["bit_generators"], label
        other.close()


def test_copies_and_pickles_are_independent_envs_in_the_same_state() -> None:
    """A user model whose contact forces need the added sensor (walker: no sensor of its own)."""
    env = BatchedMujocoEnv(
        dm_control_suite_xml("walker.xml"),
        NUM_ENVS,
        observation={"forces": R.contact_force(), "action": R.last_action()},
        state={"speed": R.finite_difference(R.subtree_com("torso")), "qpos": R.joint_pos()},
        resets=Resets(qvel_noise=Noise("normal", 0.2)),
        frame_skip=3,
        seed=4,
    )
    assert "torchtasks_contact_forces" in [env.model.sensor(s).name for s in range(env.model.nsensor)]
    env.reset()
    _run(env, _actions(env, 20, 0))
    copies = [copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    actions = _actions(env, 6, 1)
    expected = _run(env, actions, reset_at=2)
    assert any((out["forces"] != 0).any() for out in expected)
    saved = copy.deepcopy(env.state_dict())
    for each in copies:
        _assert_same_outputs(_run(each, actions, reset_at=2), expected)
        _run(each, _actions(env, 3, 2), reset_at=1)  # the copy moves on: the original does not
    after = env.state_dict()
    _assert_rows_equal(
        saved["_extra_state"]["running_episodes"], after["_extra_state"]["running_episodes"], list(range(NUM_ENVS))
    )
    for each in (env, *copies):
        each.close()


def _parallel_quadruped() -> BatchedMujocoEnv:
    return BatchedMujocoEnv(
        model_path("quadruped"),
        2,
        observation={"qpos": R.joint_pos(), "forces": R.contact_force("torso")},
        actions=Actions(scale=0.3, offset="home"),
        resets=Resets(keyframe="home", joint_noise={"FL_calf_joint": Noise("uniform", 0.1)}),
        frame_skip=4,
        seed=0,
    )


@pytest.mark.multiprocess
def test_a_parallel_env_of_batched_envs_steps(fork_start_method) -> None:
    from torchrl.envs import ParallelEnv

    parallel = ParallelEnv(2, _parallel_quadruped)
    try:
        rollout = parallel.rollout(3)
        assert rollout["next", "qpos"].shape == (2, 2, 3, 19)
        assert rollout["next", "qpos"].isfinite().all()
    finally:
        parallel.close()


# ------------------------------------------------------------------------------ broken steps
def test_a_nan_action_row_ends_that_env_and_the_others_continue_bit_for_bit() -> None:
    case = CASES["dm_control walker"]
    twin = Twin.of(case)
    env = BatchedMujocoEnv(
        case.source(),
        NUM_ENVS,
        observation={"qpos": R.joint_pos(), "qvel": R.joint_vel()},
        actions=case.actions,
        resets=case.resets,
        frame_skip=case.frame_skip,
        stage=case.stage,
        seed=case.seed,
    )
    env.reset()
    twin.reset(list(range(NUM_ENVS)))
    for k, action in enumerate(_actions(env, 6, 0)):
        if k == 3:
            action[2, 1] = float("nan")
            frozen = twin.datas[2].qpos.copy(), twin.datas[2].qvel.copy()
            with pytest.warns(RuntimeWarning, match=r"non-finite action in envs \[2\]"):
                out = env.step(TensorDict({"action": action}, [NUM_ENVS]))["next"]
            for i in (0, 1, 3):  # the reference steps the others
                twin.datas[i].ctrl[:] = twin.offset + twin.scale * action[i].double().numpy()
                for _ in range(case.frame_skip):
                    mujoco.mj_step(twin.models[i], twin.datas[i])
                mujoco.mj_step1(twin.models[i], twin.datas[i])
            assert out["broken"][:, 0].tolist() == [False, False, True, False]
            assert out["terminated"][:, 0].tolist() == [False, False, True, False]
            assert out["done"][:, 0].tolist() == [False, False, True, False]
            np.testing.assert_array_equal(out["qpos"][2].numpy(), frozen[0])  # the broken env did not move
            assert all(value.isfinite().all() for value in out.values() if value.is_floating_point())
            env.reset(TensorDict({"_reset": _mask(2)}, [NUM_ENVS]))
            twin.reset([2])
            continue
        out = env.step(TensorDict({"action": action}, [NUM_ENVS]))["next"]
        twin.step(action.double().numpy())
        assert not out["broken"].any()
        assert_state(env, twin, out, f"step {k}", list(range(NUM_ENVS)))
    env.close()


# ------------------------------------------------------------------------------ bad input
def test_bad_declarations_are_refused_naming_the_argument(tmp_path: Path) -> None:
    quadruped, obs = model_path("quadruped"), R.joint_pos()
    broken = tmp_path / "broken.xml"
    broken.write_text('<mujoco><worldbody><body><geom type="box" size="1"/><joint/></body></worldbody></mujoco>')
    walker = mujoco.MjModel.from_xml_path(str(dm_control_suite_xml("walker.xml")))

    def env(model: Any = quadruped, **kwargs: Any) -> Callable[[], Any]:
        kwargs.setdefault("observation", obs)
        return lambda: BatchedMujocoEnv(model, 2, **kwargs)

    cases = [
        (
            env(observation=R.joint_pos("FL_calf_jont")),
            r"joint_pos joints: the model has no joint 'FL_calf_jont'; "
            r"did you mean 'FL_calf_joint'",
        ),
        (
            env(observation=R.body_lin_vel("torsoo")),
            r"body_lin_vel body: the model has no body 'torsoo'; did you mean "
            r"'torso'\?",
        ),
        (
            env(observation=R.sensor("imu_gyr")),
            r"sensor name: the model has no sensor 'imu_gyr'; did you mean 'imu_gyro'",
        ),
        (
            env(observation=R.actuator_ctrl("FL_hipp")),
            r"actuator_ctrl actuators: .*no actuator 'FL_hipp'; did you "
            r"mean 'FL_hip'",
        ),
        (env(observation=R.site_pos("imuu")), r"site_pos site: the model has no site 'imuu'; did you mean 'imu'\?"),
        (env(resets=Resets(keyframe="hom")), r"Resets keyframe: the model has no keyframe 'hom'; did you mean 'home'"),
        (env(actions=Actions(offset="hom")), r"actions offset: the model has no keyframe 'hom'; did you mean 'home'"),
        (
            env(resets=Resets(joint_noise={"FL_calf_jont": Noise("uniform", 0.1)})),
            r"Resets joint_noise: the model has no joint 'FL_calf_jont'; did you mean 'FL_calf_joint'",
        ),
        (
            env(resets=Resets(joint_noise={"root": Noise("uniform", 0.1)})),
            r"Resets joint_noise: joint 'root' is not a hinge or slide joint \(use free_joint\)",
        ),
        (
            env(resets=Resets(free_joint=FreeJointRanges(joint="FL_calf_joint"))),
            r"Resets free_joint: joint 'FL_calf_joint' is not a free joint",
        ),
        (
            env(dm_control_suite_xml("walker.xml"), resets=Resets(free_joint=FreeJointRanges(yaw=(0, 1)))),
            r"Resets free_joint: the model has no free joint",
        ),
        (
            env(walker, observation=R.contact_force()),
            r"a reading needs contact forces.*this MjModel has none\. Give "
            r"the model as a file, an MJCF string or an MjSpec",
        ),
        (env(broken), rf"the model '{re.escape(str(broken))}' does not compile: Error: size 1 must be positive"),
        (
            env(tmp_path / "absent.xml"),
            rf"model must be .* the path of a model file; no file "
            rf"'{re.escape(str(tmp_path / 'absent.xml'))}'",
        ),
        (
            env(frame_skip=2, control_timestep=0.02),
            r"give frame_skip \(substeps per step\) or control_timestep "
            r"\(seconds per step\), not both; got frame_skip=2 and control_timestep=0.02",
        ),
        (
            env(control_timestep=0.012),
            r"control_timestep must be a positive multiple of the model's timestep 0.005, "
            r"got 0.012",
        ),
        (env(frame_skip=0), r"frame_skip must be a positive int \(substeps per step\), got 0"),
        (env(actions=Actions(scale=0.0)), r"actions scale must be > 0 for every actuator, got 0.0"),
        (env(actions=Actions(scale=[1.0] * 11 + [-1.0])), r"actions scale must be > 0 for every actuator, got \[1.0"),
        (
            env(actions=Actions(scale=[1.0] * 3)),
            r"actions scale must be a number or 12 numbers \(one per actuator\), "
            r"got \[1.0, 1.0, 1.0\]",
        ),
        (env(actions=Actions(offset=[0.0] * 13)), r"actions offset must be a number or 12 numbers"),
        (
            env(dm_control_suite_xml("quadruped.xml"), actions=Actions(offset="qpos0")),
            r"actions offset='qpos0' takes each actuator's joint position, but actuator 'lift_front_left' does not "
            r"drive a hinge or slide joint",
        ),
        (env(stage="acceleration"), r"stage must be 'velocity' or 'step', got 'acceleration'"),
    ]
    for make, match in cases:
        with pytest.raises(ValueError, match=match):
            make()
    type_cases = [
        (
            env(xml_file="x.xml"),
            r"BatchedMujocoEnv got unexpected keyword argument\(s\) \['xml_file'\]: they are the "
            r"keywords of a Gymnasium id",
        ),
        (env(task_state_keys=["qpos"]), r"unexpected keyword argument\(s\) \['task_state_keys'\]"),
        (
            env("Hopper-v5", observation=obs, resets=Resets()),
            r"Hopper-v5 is a Gymnasium preset declared by torchtasks: "
            r"it takes Gymnasium's keyword arguments \(and task_state_keys\), not \['observation', 'resets'\]",
        ),
        (
            env("Hopper-v5", observation=None, control_timestep=0.008, stage="step"),
            r"Hopper-v5 is a Gymnasium preset .*not \['control_timestep', 'stage'\]",
        ),
    ]
    for make, match in type_cases:
        with pytest.raises(TypeError, match=match):
            make()
