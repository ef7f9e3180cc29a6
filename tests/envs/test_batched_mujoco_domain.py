"""BatchedMujocoEnv's per-env physics (the DomainEnv methods): trajectories, set_const, checks, checkpoints.

The reference of every trajectory is one Gymnasium v5 env per batch entry whose ``MjModel`` is a copy of the
nominal model set by hand to that env's values (``reference_model`` below: the mass with the inertia scaled by
value / nominal mass, the sliding friction, the dofs' damping and armature, the gear, gravity; a scale times every
object's nominal value; ``mujoco.mj_setConst`` when a mass, armature or gear was set) and whose ``MjData`` starts
from the batched env's state after each reset. Gymnasium steps it (``mj_step`` ``frame_skip`` times, then
``mj_rnePostConstraint``) and computes the observation and ``info``; the batched env must give the same ``qpos``,
``qvel``, observation and task-state entries bit for bit, through a ``set_domain`` on some envs mid-episode and a
partial reset with new values.
"""

from __future__ import annotations

import copy
import pickle
from typing import Any

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco")
gymnasium = pytest.importorskip("gymnasium")

import mujoco  # noqa: E402
from tensordict import TensorDict  # noqa: E402

from torchtasks.domain import DomainEnv  # noqa: E402
from torchtasks.envs import BatchedMujocoEnv  # noqa: E402

pytestmark = pytest.mark.mujoco

NUM_ENVS = 4
STEPS = 210
#: the step after which some envs get new values mid-episode, and the one after which others are reset with new ones
MID_EPISODE, PARTIAL_RESET = 70, 140
MID_MASK = [True, False, True, False]
RESET_MASK = [False, True, True, False]
#: env 3 is never written at the start: it runs on the nominal model beside the others
FIRST_MASK = [True, True, True, False]

#: the fields set per case; each case covers its kinds' one-object fields or their scales (never both in one call)
CASES: dict[str, tuple[str, list[str]]] = {
    "hopper-objects": (
        "Hopper-v5",
        [
            "body_mass:thigh",
            "geom_friction:foot_geom",
            "dof_damping:leg_joint",
            "dof_armature:foot_joint",
            "actuator_gear_scale",  # Hopper's actuators are unnamed: the scale is its only gear field
            "gravity",
        ],
    ),
    "hopper-scales": (
        "Hopper-v5",
        [
            "body_mass_scale",
            "geom_friction_scale",
            "dof_damping_scale",
            "dof_armature_scale",
            "actuator_gear_scale",
            "gravity",
        ],
    ),
    # no field that needs set_const: gravity and the passive fields alone
    "hopper-no-set-const": ("Hopper-v5", ["geom_friction_scale", "dof_damping:thigh_joint", "gravity"]),
    # contact forces (persistent batch, mj_rnePostConstraint per env); a free joint's dofs: value shape (6,)
    "ant": ("Ant-v5", ["body_mass:torso", "geom_friction:floor", "dof_damping:root", "dof_armature:hip_1", "gravity"]),
    # the mass centre (x_velocity from per-env masses), named actuators
    "humanoid": ("Humanoid-v5", ["body_mass_scale", "actuator_gear:right_knee", "geom_friction_scale", "gravity"]),
    # poses: a body moved and turned in its parent, a geom moved on its body (rows of 3 and 4 values, no scale)
    "hopper-poses": ("Hopper-v5", ["body_pos:foot", "body_quat:thigh", "geom_pos:foot_geom", "body_mass:leg"]),
}

#: fields whose model field mj_setConst reads (mujoco.MjModel._setconst_inputs)
SET_CONST_KINDS = ("body_mass", "dof_armature", "actuator_gear", "body_pos", "body_quat", "geom_pos", "site_pos")
#: the kinds of an object's pose, and the kind of object each belongs to
POSE_KINDS = {"body_pos": "body", "body_quat": "body", "geom_pos": "geom", "site_pos": "site"}


# ------------------------------------------------------------------------------ the reference
def _parse(name: str) -> tuple[str, str | None]:
    """``"body_mass:torso"`` -> ("body_mass", "torso"); ``"body_mass_scale"`` -> ("body_mass", None)."""
    if ":" in name:
        kind, obj = name.split(":")
        return kind, obj
    return name.removesuffix("_scale"), None


def reference_model(nominal: mujoco.MjModel, values: dict[str, np.ndarray]) -> mujoco.MjModel:
    """A copy of ``nominal`` set by hand to one env's ``values`` (name -> value), with mj_setConst when needed."""
    model = copy.copy(nominal)
    for name, value in values.items():
        kind, obj = _parse(name)
        if name == "gravity":
            model.opt.gravity[:] = value
        elif kind == "body_mass" and obj is not None:
            body = nominal.body(obj).id
            model.body_mass[body] = value
            model.body_inertia[body] = nominal.body_inertia[body] * (value / nominal.body_mass[body])
        elif kind == "body_mass":
            model.body_mass[:] = nominal.body_mass * value
            model.body_inertia[:] = nominal.body_inertia * value
        elif kind == "geom_friction":
            rows = slice(None) if obj is None else nominal.geom(obj).id
            model.geom_friction[rows, 0] = nominal.geom_friction[rows, 0] * value if obj is None else value
        elif kind in ("dof_damping", "dof_armature"):
            if obj is None:
                getattr(model, kind)[:] = getattr(nominal, kind) * value
            else:
                joint = nominal.joint(obj)
                start, count = int(joint.dofadr[0]), {0: 6, 1: 3}.get(int(joint.type[0]), 1)
                getattr(model, kind)[start : start + count] = value
        elif kind in POSE_KINDS:
            getattr(model, kind)[getattr(nominal, POSE_KINDS[kind])(obj).id] = value
        elif kind == "actuator_gear":
            rows = slice(None) if obj is None else nominal.actuator(obj).id
            model.actuator_gear[rows, 0] = nominal.actuator_gear[rows, 0] * value if obj is None else value
        else:
            raise AssertionError(name)
    if any(_parse(name)[0] in SET_CONST_KINDS for name in values):
        mujoco.mj_setConst(model, mujoco.MjData(model))  # a scratch MjData: mj_setConst computes at qpos0
    return model


def draw_values(env: BatchedMujocoEnv, names: list[str], rng: np.random.Generator) -> dict[str, torch.Tensor]:
    """Per-env values around the nominal ones (factors in [0.6, 1.4]; env 1's gear flipped when it is one object's)."""
    values = {}
    for field in env.domain_fields(names):
        nominal = field.nominal.numpy()
        shape = (NUM_ENVS, *field.value_shape)
        if field.name == "gravity":
            value = nominal + rng.uniform(-2.0, 2.0, size=shape)
        elif field.name.startswith("body_quat:"):  # a unit quaternion near the nominal one
            value = nominal + rng.uniform(-0.2, 0.2, size=shape)
            value /= np.linalg.norm(value, axis=1, keepdims=True)
        elif _parse(field.name)[0] in POSE_KINDS:
            value = nominal + rng.uniform(-0.05, 0.05, size=shape)
        else:
            value = nominal * rng.uniform(0.6, 1.4, size=shape)
            if field.name.startswith("actuator_gear:"):
                value[1] = -value[1]  # any finite gear: a reversed actuator
        values[field.name] = torch.from_numpy(value)
    return values


class Reference:
    """Gymnasium envs on per-env model copies, stepped beside the batched env."""

    def __init__(self, env: BatchedMujocoEnv) -> None:
        self.env, self.nominal = env, env.model
        self.gym = [gymnasium.make(env.env_id).unwrapped for _ in range(NUM_ENVS)]
        self.values: list[dict[str, np.ndarray]] = [{} for _ in range(NUM_ENVS)]
        for i in range(NUM_ENVS):
            self._install(i)

    def _install(self, i: int) -> None:
        self.gym[i].model = reference_model(self.nominal, self.values[i])

    def set(self, values: dict[str, torch.Tensor], mask: list[bool]) -> None:
        for i in np.flatnonzero(mask).tolist():
            self.values[i].update({name: value[i].numpy() for name, value in values.items()})
            self._install(i)

    def restart(self, ids: list[int]) -> None:
        """Start envs ``ids`` from the batched env's state (after its reset), as Gymnasium's reset leaves it."""
        for i in ids:
            gym = self.gym[i]
            gym.data = self.env.batch.get_data(i, mujoco.MjData(gym.model))
            mujoco.mj_forward(gym.model, gym.data)

    def step(self, action: torch.Tensor) -> list[tuple[np.ndarray, dict[str, Any]]]:
        out = []
        for gym, row in zip(self.gym, action.numpy(), strict=True):
            observation, _, _, _, info = gym.step(row)
            out.append((observation, info))
        return out


def _assert_models_are_the_references(env: BatchedMujocoEnv, ref: Reference) -> None:
    """Each env's model (``Batch.get_model``: the batch's with the env's per-env fields and derived constants) equals
    its reference in every array and option, and so does the model its contact forces are computed with."""
    names = [name for name in dir(env.model) if isinstance(getattr(env.model, name), np.ndarray)]
    for i in range(NUM_ENVS):
        reference = ref.gym[i].model
        models = [env.batch.get_model(i)]
        if env._contact_forces is not None:
            models.append(env._env_models[i])
        for model in models:
            for name in names:
                np.testing.assert_array_equal(getattr(model, name), getattr(reference, name), err_msg=f"{i} {name}")
            np.testing.assert_array_equal(model.opt.gravity, reference.opt.gravity)


def _assert_same(env: BatchedMujocoEnv, ref: Reference, out: TensorDict, stepped: list, step: int) -> None:
    for i, (observation, info) in enumerate(stepped):
        data = ref.gym[i].data
        context = f"{env.env_id} env {i} step {step}"
        np.testing.assert_array_equal(env.batch.qpos[i], data.qpos, err_msg=context)
        np.testing.assert_array_equal(env.batch.qvel[i], data.qvel, err_msg=context)
        np.testing.assert_array_equal(out["observation"][i].numpy(), observation, err_msg=context)
        expected = {
            "x_velocity": [info["x_velocity"]],
            "qpos": data.qpos,
            "qvel": data.qvel,
            "cfrc_ext": data.cfrc_ext.flatten(),
        }
        for key in env.state_layout:
            np.testing.assert_array_equal(out[key][i].numpy(), expected[key], err_msg=f"{context} {key}")


@pytest.mark.parametrize("case", list(CASES))
def test_trajectories_equal_per_env_model_copies_bit_for_bit(case: str) -> None:
    env_id, names = CASES[case]
    env = BatchedMujocoEnv(env_id, NUM_ENVS, seed=0, num_threads=2)
    rng = np.random.default_rng(0)
    ref = Reference(env)
    first = draw_values(env, names, rng)
    env.set_domain(first, torch.tensor(FIRST_MASK))
    ref.set(first, FIRST_MASK)
    _assert_models_are_the_references(env, ref)
    env.reset()
    ref.restart(list(range(NUM_ENVS)))
    low, high = env.model.actuator_ctrlrange.T
    for step in range(STEPS):
        if step == MID_EPISODE:  # new values for running episodes
            values = draw_values(env, names, rng)
            env.set_domain(values, torch.tensor(MID_MASK))
            ref.set(values, MID_MASK)
            _assert_models_are_the_references(env, ref)
        if step == PARTIAL_RESET:  # new values, then a reset of those envs only
            values = draw_values(env, names, rng)
            env.set_domain(values, torch.tensor(RESET_MASK))
            ref.set(values, RESET_MASK)
            _assert_models_are_the_references(env, ref)
            env.reset(TensorDict({"_reset": torch.tensor(RESET_MASK)[:, None]}, batch_size=[NUM_ENVS]))
            ref.restart(np.flatnonzero(RESET_MASK).tolist())
        action = torch.from_numpy(rng.uniform(low, high, size=(NUM_ENVS, env.model.nu)))
        out = env.step(TensorDict({"action": action}, batch_size=[NUM_ENVS]))["next"]
        _assert_same(env, ref, out, ref.step(action), step)
    # the values are what was set, env by env (env 3: nominal for the fields first set on the others)
    now = env.domain_values(names)
    for i in range(NUM_ENVS):
        for name in names:
            want = ref.values[i].get(name, env.domain_fields([name])[0].nominal.numpy())
            np.testing.assert_array_equal(now[name][i].numpy(), want)
    env.close()


# ------------------------------------------------------------------------------ set_const and expansion
def _spy_set_const(env: BatchedMujocoEnv) -> list[Any]:
    calls: list[Any] = []
    original = env.batch.set_const

    def set_const(ids: Any = None) -> None:
        calls.append(None if ids is None else np.asarray(ids).tolist())
        original(ids)

    env.batch.set_const = set_const
    return calls


def _ones(env: BatchedMujocoEnv, name: str, factor: float = 1.2) -> torch.Tensor:
    field = env.domain_fields([name])[0]
    return (field.nominal * factor).expand(NUM_ENVS, *field.value_shape).clone()


@pytest.mark.parametrize(
    ("names", "mask", "want"),
    [
        (["geom_friction:floor", "dof_damping:thigh_joint", "gravity"], None, []),  # no set_const input
        (["body_mass:torso"], [False, True, False, True], [[1, 3]]),
        (["dof_armature_scale", "geom_friction_scale"], [True, False, False, False], [[0]]),
        (["actuator_gear_scale", "body_mass_scale", "dof_armature:foot_joint"], None, [None]),  # once for all
        (["body_mass:torso"], [False] * NUM_ENVS, []),  # no env written
    ],
)
def test_set_const_runs_once_over_the_written_envs_only_for_fields_that_need_it(
    names: list[str], mask: list[bool] | None, want: list[Any]
) -> None:
    env = BatchedMujocoEnv("Hopper-v5", NUM_ENVS, seed=0)
    calls = _spy_set_const(env)
    env.set_domain({name: _ones(env, name) for name in names}, None if mask is None else torch.tensor(mask))
    assert calls == want
    env.close()


def test_an_env_never_given_values_expands_no_model_field() -> None:
    env = BatchedMujocoEnv("Ant-v5", NUM_ENVS, seed=0)
    assert isinstance(env, DomainEnv)
    env.rollout(3)
    env.domain_values()  # reading is not writing
    copy.deepcopy(env).close()
    env.load_state_dict(env.state_dict())
    fields = env.domain_fields()
    written = {name for field in fields for name in field.model_fields}
    derived = ("body_subtreemass", "body_invweight0", "dof_invweight0", "dof_M0", "actuator_acc0")
    assert {"body_mass", "body_inertia", "geom_friction", "opt.gravity"} <= written
    for name in (*written, *derived):
        assert env.batch.expanded(name) is None, name
    assert env._env_models is None
    # writing friction expands friction only
    env.set_domain({"geom_friction_scale": _ones(env, "geom_friction_scale")})
    assert env.batch.expanded("geom_friction") is not None
    for name in written - {"geom_friction"}:
        assert env.batch.expanded(name) is None, name
    env.close()


def test_the_fields_of_an_env() -> None:
    env = BatchedMujocoEnv("Ant-v5", 2, seed=0)
    fields = {field.name: field for field in env.domain_fields()}
    model = env.model
    # named bodies but the world body (Ant's lower legs are unnamed), every named geom, joint; no actuator is named:
    # each is offered by the name of the joint it drives
    bodies = [model.body(i).name for i in range(1, model.nbody) if model.body(i).name]
    assert [name.split(":")[1] for name in fields if name.startswith("body_mass:")] == bodies
    driven = [model.joint(int(model.actuator_trnid[i, 0])).name for i in range(model.nu)]
    assert [name.split(":")[1] for name in fields if name.startswith("actuator_gear:")] == driven
    assert all(not model.actuator(i).name for i in range(model.nu))
    assert fields["dof_damping:root"].value_shape == (6,) and fields["dof_damping:hip_1"].value_shape == ()
    assert fields["gravity"].value_shape == (3,) and fields["gravity"].rule == "finite"
    assert fields["body_mass:torso"].nominal.item() == model.body("torso").mass[0]
    assert fields["body_mass:torso"].model_fields == ("body_mass", "body_inertia")
    rules = {name: fields[name].rule for name in ("body_mass_scale", "geom_friction:floor", "actuator_gear_scale")}
    assert rules == {
        "body_mass_scale": "in (0.0, inf)",
        "geom_friction:floor": "in [0.0, inf)",
        "actuator_gear_scale": "in (0.0, inf)",
    }
    assert all(fields[name].nominal.item() == 1.0 for name in fields if name.endswith("_scale"))
    assert [field.name for field in env.domain_fields(["gravity", "body_mass:torso"])] == ["gravity", "body_mass:torso"]
    humanoid = BatchedMujocoEnv("Humanoid-v5", 1)
    gear = humanoid.domain_fields(["actuator_gear:right_knee"])[0]
    assert gear.rule == "finite" and gear.nominal.item() == humanoid.model.actuator("right_knee").gear[0]
    env.close()
    humanoid.close()


# ------------------------------------------------------------------------------ bad input
def _values(env: BatchedMujocoEnv, name: str, value: Any) -> dict[str, Any]:
    return {name: value}


BAD_VALUES = [
    ("body_mass:torso", 0.0, ValueError, r"'body_mass:torso'.* of env 2 is 0\.0.*must be in \(0\.0, inf\)"),
    ("geom_friction:floor", -1.0, ValueError, r"of env 2 is -1\.0.*must be in \[0\.0, inf\)"),
    ("body_mass_scale", -1.0, ValueError, r"'body_mass_scale'.* of env 2 is -1\.0.*must be in \(0\.0, inf\)"),
    ("actuator_gear_scale", 0.0, ValueError, r"never reverses.*must be in \(0\.0, inf\)"),
    ("dof_damping:thigh_joint", float("nan"), ValueError, r"of env 2 is nan"),
    ("gravity", float("inf"), ValueError, r"'gravity'.* of env 2 is \[inf, inf, inf\].*must be finite"),
]


@pytest.mark.parametrize(("name", "bad", "error", "match"), BAD_VALUES)
def test_out_of_range_and_non_finite_values_of_the_written_envs_are_refused(
    name: str, bad: float, error: type[Exception], match: str
) -> None:
    env = BatchedMujocoEnv("Hopper-v5", NUM_ENVS, seed=0)
    values = _ones(env, name)
    values[2] = bad
    before = env.domain_values([name])[name]
    with pytest.raises(error, match=match):
        env.set_domain({name: values})
    with pytest.raises(error, match=match):
        env.set_domain({name: values}, torch.tensor([False, False, True, False]))
    assert torch.equal(env.domain_values([name])[name], before)  # nothing written
    assert env.batch.expanded(env.domain_fields([name])[0].model_fields[0]) is None
    env.set_domain({name: values}, torch.tensor([True, True, False, True]))  # env 2's row is ignored
    assert torch.equal(env.domain_values([name])[name][2], before[2])
    env.close()


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (
            lambda env: env.domain_fields(["body_mass:torsoo"]),
            ValueError,
            r"unknown domain field 'body_mass:torsoo' in names; did you mean 'body_mass:torso'.*"
            # 4 + 5 + 6 + 6 + 3 objects, 5 scales, gravity; poses of 4 + 4 bodies and 5 geoms; the 3 motors' gains
            # and their scale (no servo: no kp, no kv)
            r"env\.domain_fields\(\) lists all 47 fields",
        ),
        (
            lambda env: env.set_domain({"mass:torso": torch.ones(NUM_ENVS, dtype=torch.float64)}),
            ValueError,
            r"'mass:torso' in values; did you mean 'body_mass:torso'\? "
            r"\(kinds: body_mass:<body>, body_mass_scale, .*gravity; env\.domain_fields\(\) lists all 47",
        ),
        (lambda env: env.domain_fields("gravity"), TypeError, r"names must be a sequence"),
        (
            lambda env: env.domain_fields(["body_mass_scale", "body_mass:torso"]),
            ValueError,
            r"'body_mass_scale' and 'body_mass:torso' both write body_mass",
        ),
        (lambda env: env.domain_fields(["gravity", "gravity"]), ValueError, r"'gravity' is named twice"),
        (
            lambda env: env.set_domain({"body_mass:torso": torch.ones(NUM_ENVS, dtype=torch.float32)}),
            TypeError,
            r"values\['body_mass:torso'\] must be a float64 tensor of shape \[4\].*got dtype torch\.float32",
        ),
        (
            lambda env: env.set_domain({"gravity": torch.ones(NUM_ENVS, dtype=torch.float64)}),
            ValueError,
            r"values\['gravity'\] must be a float64 tensor of shape \[4, 3\].*got shape \[4\]",
        ),
        (
            lambda env: env.set_domain({"body_mass:torso": [1.0] * NUM_ENVS}),
            TypeError,
            r"must be a float64 tensor .*got a list",
        ),
        (lambda env: env.set_domain([("gravity", None)]), TypeError, r"values must be a mapping"),
        (
            lambda env: env.set_domain({}, torch.ones(NUM_ENVS)),
            TypeError,
            r"mask must be a bool tensor of shape \[4\] or None, got dtype torch\.float32",
        ),
        (
            lambda env: env.set_domain({}, torch.ones(NUM_ENVS, 1, dtype=torch.bool)),
            ValueError,
            r"mask must be a bool tensor of shape \[4\].*got shape \[4, 1\]",
        ),
    ],
)
def test_bad_names_shapes_dtypes_and_masks_are_refused_by_name(call: Any, error: type[Exception], match: str) -> None:
    env = BatchedMujocoEnv("Hopper-v5", NUM_ENVS, seed=0)
    with pytest.raises(error, match=match):
        call(env)
    env.close()


# ------------------------------------------------------------------------------ checkpoints, copies, pickles
def _run(env: BatchedMujocoEnv, steps: int, seed: int) -> list[torch.Tensor]:
    """Observations of ``steps`` steps with seeded actions, a partial reset in the middle."""
    rng = np.random.default_rng(seed)
    low, high = env.model.actuator_ctrlrange.T
    out = []
    for step in range(steps):
        if step == steps // 2:
            env.reset(TensorDict({"_reset": torch.tensor(RESET_MASK)[:, None]}, batch_size=[NUM_ENVS]))
        action = torch.from_numpy(rng.uniform(low, high, size=(NUM_ENVS, env.model.nu)))
        next_ = env.step(TensorDict({"action": action}, batch_size=[NUM_ENVS]))["next"]
        out.append(torch.cat([next_[key] for key in ("observation", *env.state_layout)], dim=-1))
    return out


def _randomized(env_id: str) -> BatchedMujocoEnv:
    """An env in mid-episode with values set by two calls (a scale and one object's value of the same kind)."""
    env = BatchedMujocoEnv(env_id, NUM_ENVS, seed=3)
    rng = np.random.default_rng(1)
    env.set_domain(draw_values(env, ["body_mass_scale", "gravity", "geom_friction_scale"], rng))
    env.reset()
    _run(env, 10, seed=5)
    env.set_domain(draw_values(env, ["body_mass:torso", "dof_armature_scale"], rng), torch.tensor(MID_MASK))
    return env


@pytest.mark.parametrize("env_id", ["Hopper-v5", "Humanoid-v5"])
def test_checkpoints_copies_and_pickles_keep_the_physics_and_continue_bit_for_bit(env_id: str) -> None:
    env = _randomized(env_id)
    state = env.state_dict()
    loaded = BatchedMujocoEnv(env_id, NUM_ENVS, seed=0)
    loaded.load_state_dict(state)
    others = [loaded, copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    values = env.domain_values()
    want = _run(env, 30, seed=7)
    for other in others:
        for name, value in other.domain_values().items():
            assert torch.equal(value, values[name]), name
        for got, expected in zip(_run(other, 30, seed=7), want, strict=True):
            assert torch.equal(got, expected)
        other.close()
    env.close()


def test_a_checkpoint_puts_fields_it_does_not_hold_back_to_nominal_and_an_old_one_still_loads() -> None:
    nominal = BatchedMujocoEnv("Hopper-v5", NUM_ENVS, seed=3)
    nominal.reset()
    _run(nominal, 10, seed=5)
    state = nominal.state_dict()
    old = copy.deepcopy(state)
    del old["_extra_state"]["running_episodes"]["domain"]  # as written before the env saved its physics
    want = _run(nominal, 30, seed=7)
    for saved in (state, old):
        env = _randomized("Hopper-v5")
        env.load_state_dict(saved)
        for name, value in env.domain_values().items():
            assert torch.equal(value, env.domain_fields([name])[0].nominal.expand_as(value)), name
        for got, expected in zip(_run(env, 30, seed=7), want, strict=True):
            assert torch.equal(got, expected)
        env.close()
    nominal.close()


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda domain: domain.update({"body_mass:nose": domain.pop("body_mass:torso")}), r"unknown domain field"),
        (lambda domain: domain.update({"gravity": torch.zeros(NUM_ENVS, 2, dtype=torch.float64)}), r"shape \[4, 3\]"),
        (lambda domain: domain.update({"body_mass_scale": -domain["body_mass_scale"]}), r"must be in \(0\.0, inf\)"),
    ],
)
def test_a_saved_domain_of_unknown_names_shapes_or_values_is_refused(edit: Any, match: str) -> None:
    env = _randomized("Hopper-v5")
    state = env.state_dict()
    edit(state["_extra_state"]["running_episodes"]["domain"])
    fresh = BatchedMujocoEnv("Hopper-v5", NUM_ENVS, seed=0)
    with pytest.raises(ValueError, match=match):
        fresh.load_state_dict(state)
    assert fresh.batch.expanded("body_mass") is None  # refused before anything was written
    env.close()
    fresh.close()
