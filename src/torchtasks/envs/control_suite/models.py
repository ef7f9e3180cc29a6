"""The DeepMind Control Suite's models, built as dm_control's ``suite.load`` builds them, without dm_control.

The suite's MJCF files ship with torchtasks, unchanged from dm-control 1.0.50 (``torchtasks/envs/models/dm_control/``,
Apache-2.0, with dm_control's licence). :func:`control_suite_spec` parses a domain's file with the common files it
includes (passed as dm_control passes them: ``./common/materials.xml``, ``./common/skybox.xml`` and
``./common/visual.xml``) and makes the edits dm_control makes to the XML for the task, here on a ``mujoco.MjSpec``:

- quadruped walk and run: the floor is ``time_limit * speed`` wide (10 and 100 m); the walls, the ball (with its free
  joint), the target site, the heightfield geom ``terrain`` and every rangefinder sensor are removed;
- swimmer6 and swimmer15: the chain of ``n - 1`` links is generated after the head, as dm_control's
  ``swimmer._make_model(n)`` does (joint ranges ``±360/n`` degrees, a motor, a velocimeter and a gyro per link, the
  ``trackcom`` cameras moved ``n/6`` times further);
- manipulator bring_ball: the unused props (bodies ``cup``, ``peg``, ``target_peg`` and ``slot``) are removed;
- the others (cartpole's single pole included) use the file as it is.

:func:`control_suite_model` compiles that spec and writes the model values a task's reset writes with the same value
at every episode (:data:`FIXED_MODEL_EDITS`: finger spin's spinner damping, finger turn's and reacher's target
sizes, and the targets' transparency), so its physics and readings are those of dm_control's episodes. Values a
reset draws per episode (targets' positions) are not in the model: a task draws them. :data:`TASKS` lists the
domains and tasks: the 28 of dm_control's ``BENCHMARKING`` and quadruped walk and run.
"""

from __future__ import annotations

import copy
import functools
import importlib.resources
import types
import warnings
from collections.abc import Callable, Mapping
from typing import NamedTuple

from torchtasks._did_you_mean import did_you_mean
from torchtasks._optional import missing_extra

try:
    import mujoco
except ImportError as _error:
    raise missing_extra("mujoco", "torchtasks.envs.control_suite", _error) from _error

__all__ = ["FIXED_MODEL_EDITS", "TASKS", "ModelEdit", "control_suite_model", "control_suite_spec"]

#: the domains and their tasks (a literal: ``torchtasks check`` reads it from the source without importing MuJoCo)
_TASK_TABLE = {
    "acrobot": ("swingup", "swingup_sparse"),
    "ball_in_cup": ("catch",),
    "cartpole": ("balance", "balance_sparse", "swingup", "swingup_sparse"),
    "cheetah": ("run",),
    "finger": ("spin", "turn_easy", "turn_hard"),
    "fish": ("upright", "swim"),
    "hopper": ("stand", "hop"),
    "humanoid": ("stand", "walk", "run"),
    "manipulator": ("bring_ball",),
    "pendulum": ("swingup",),
    "point_mass": ("easy",),
    "reacher": ("easy", "hard"),
    "swimmer": ("swimmer6", "swimmer15"),
    "walker": ("stand", "walk", "run"),
    "quadruped": ("walk", "run"),
}
#: the domains and their tasks: dm_control's BENCHMARKING tasks (dm-control 1.0.50) and quadruped walk and run
TASKS: Mapping[str, tuple[str, ...]] = types.MappingProxyType(_TASK_TABLE)
#: the files the domain files include, under the names dm_control gives them (``dm_control.suite.common.ASSETS``)
_COMMON_FILES = ("./common/materials.xml", "./common/skybox.xml", "./common/visual.xml")


class ModelEdit(NamedTuple):
    """One value dm_control's reset writes into the model, the same at every episode.

    ``field`` is the ``mujoco.MjModel`` field, ``name`` the object's name (a joint for ``dof_*`` fields, else an
    object of the field's kind: ``site_*`` a site, ``geom_*`` a geom), ``column`` the column written (``None`` for
    a field with one value per object) and ``value`` the value.

    Example:
        >>> from torchtasks.envs.control_suite.models import FIXED_MODEL_EDITS
        >>> FIXED_MODEL_EDITS["reacher", "hard"]
        (ModelEdit(field='geom_size', name='target', column=0, value=0.015),)
    """

    field: str
    name: str
    column: int | None
    value: float


#: the values a task's reset writes into the model with the same value at every episode (dm-control 1.0.50's
#: ``initialize_episode``), written by :func:`control_suite_model` once. The alpha edits are visual only; they
#: are kept so that the model equals dm_control's after a reset in every field.
FIXED_MODEL_EDITS: Mapping[tuple[str, str], tuple[ModelEdit, ...]] = types.MappingProxyType(
    {
        ("finger", "spin"): (
            ModelEdit("site_rgba", "target", 3, 0.0),
            ModelEdit("site_rgba", "tip", 3, 0.0),
            ModelEdit("dof_damping", "hinge", None, 0.03),
        ),
        ("finger", "turn_easy"): (ModelEdit("site_size", "target", 0, 0.07),),
        ("finger", "turn_hard"): (ModelEdit("site_size", "target", 0, 0.03),),
        ("fish", "upright"): (ModelEdit("geom_rgba", "target", 3, 0.0),),
        ("reacher", "easy"): (ModelEdit("geom_size", "target", 0, 0.05),),
        ("reacher", "hard"): (ModelEdit("geom_size", "target", 0, 0.015),),
    }
)

#: quadruped's episode length (s); its floor is this times the task's speed wide (quadruped.make_model)
_QUADRUPED_TIME_LIMIT = 20.0
#: the sensor types quadruped walk and run remove (every rangefinder)
_QUADRUPED_RANGEFINDER = mujoco.mjtSensor.mjSENS_RANGEFINDER


def _quadruped_without_extras(spec: mujoco.MjSpec, speed: float) -> None:
    """quadruped.make_model(floor_size=time_limit * speed): no walls, ball, target, terrain or rangefinders."""
    floor_size = _QUADRUPED_TIME_LIMIT * speed
    spec.geom("floor").size = [floor_size, floor_size, 0.5]
    for geom in ("wall_px", "wall_py", "wall_nx", "wall_ny", "terrain"):
        spec.delete(spec.geom(geom))
    spec.delete(spec.body("ball"))
    spec.delete(spec.site("target"))
    for sensor in [sensor for sensor in spec.sensors if sensor.type == _QUADRUPED_RANGEFINDER]:
        spec.delete(sensor)


#: the sensors on each swimmer link's site, in order
_SWIMMER_LINK_SENSORS = (("velocimeter", mujoco.mjtSensor.mjSENS_VELOCIMETER), ("gyro", mujoco.mjtSensor.mjSENS_GYRO))


def _swimmer_chain(spec: mujoco.MjSpec, n_bodies: int) -> None:
    """swimmer._make_model(n_bodies): ``n_bodies - 1`` links after the head, each the child of the previous."""
    swimmer, visual, inertial = (spec.find_default(name) for name in ("swimmer", "visual", "inertial"))
    head = spec.body("head")
    limit = 360.0 / n_bodies  # degrees, as the file's compiler reads angles
    parent = head
    for index in range(n_bodies - 1):
        child = parent.add_body(name=f"segment_{index}", pos=[0.0, 0.1, 0.0])
        child.add_geom(default=visual, name=f"visual_{index}")
        child.add_geom(default=inertial, name=f"inertial_{index}")
        child.add_site(default=swimmer, name=f"site_{index}")
        child.add_joint(default=swimmer, name=f"joint_{index}", range=[-limit, limit])
        motor = spec.add_actuator(name=f"motor_{index}", target=f"joint_{index}", trntype=mujoco.mjtTrn.mjTRN_JOINT)
        motor.set_to_motor()
        for kind, sensor_type in _SWIMMER_LINK_SENSORS:
            site = mujoco.mjtObj.mjOBJ_SITE
            spec.add_sensor(name=f"{kind}_{index}", type=sensor_type, objtype=site, objname=f"site_{index}")
        parent = child
    # the tracking cameras move further away with the swimmer's length
    for camera in head.cameras:
        if camera.mode == mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM:
            camera.pos = camera.pos * (n_bodies / 6.0)


def _remove_bodies(spec: mujoco.MjSpec, names: tuple[str, ...]) -> None:
    for name in names:
        spec.delete(spec.body(name))


#: the edits dm_control makes to a domain's XML for a task (the tasks not listed use the file as it is)
_SPEC_EDITS: Mapping[tuple[str, str], Callable[[mujoco.MjSpec], None]] = types.MappingProxyType(
    {
        ("quadruped", "walk"): functools.partial(_quadruped_without_extras, speed=0.5),
        ("quadruped", "run"): functools.partial(_quadruped_without_extras, speed=5.0),
        ("swimmer", "swimmer6"): functools.partial(_swimmer_chain, n_bodies=6),
        ("swimmer", "swimmer15"): functools.partial(_swimmer_chain, n_bodies=15),
        # manipulator.make_model(use_peg=False, insert=False) keeps the props "ball" and "target_ball"
        ("manipulator", "bring_ball"): functools.partial(_remove_bodies, names=("cup", "peg", "target_peg", "slot")),
    }
)


#: the notice MuJoCo 4 gives when a spec with ``settotalmass`` (cheetah.xml) compiles
_SETTOTALMASS_NOTICE = "compiler attribute 'settotalmass' is deprecated"


def _files() -> importlib.resources.abc.Traversable:
    return importlib.resources.files("torchtasks.envs.models").joinpath("dm_control")


@functools.cache
def _common_files() -> dict[str, bytes]:
    folder = _files()
    return {name: folder.joinpath(name.removeprefix("./")).read_bytes() for name in _COMMON_FILES}


def _check_task(domain: object, task: object) -> None:
    if not isinstance(domain, str):
        raise TypeError(f"domain must be a string naming a Control Suite domain, got {type(domain).__name__}")
    if not isinstance(task, str):
        raise TypeError(f"task must be a string naming a task of domain {domain!r}, got {type(task).__name__}")
    if domain not in TASKS:
        listed = ", ".join(repr(name) for name in TASKS)
        hint = did_you_mean(domain, TASKS, cutoff=0.6)
        raise ValueError(f"domain: no Control Suite domain {domain!r}{hint} (the domains: {listed})")
    if task not in TASKS[domain]:
        listed = ", ".join(repr(name) for name in TASKS[domain])
        hint = did_you_mean(task, TASKS[domain], cutoff=0.6)
        raise ValueError(f"task: domain {domain!r} has no task {task!r}{hint} (its tasks: {listed})")


def control_suite_spec(domain: str, task: str) -> mujoco.MjSpec:
    """The ``mujoco.MjSpec`` of a Control Suite task's model: the XML dm_control compiles for it, as a spec.

    It is the domain's file (shipped unchanged from dm-control 1.0.50) with its included common files and
    dm_control's edits for the task (quadruped walk/run, swimmer6/15, manipulator bring_ball; see the module's
    docstring). Compiled, it equals dm_control's model right after ``suite.load(domain, task)``;
    :func:`control_suite_model` also writes the task's :data:`FIXED_MODEL_EDITS`, which dm_control writes at every
    reset. A new spec is parsed at every call, so it can be edited freely.

    Args:
        domain: a domain of :data:`TASKS`, e.g. ``"walker"``.
        task: one of the domain's tasks, e.g. ``"walk"``.

    Raises ``TypeError`` when ``domain`` or ``task`` is not a string, and ``ValueError`` naming the closest domains
    or tasks when there is no such domain or task.

    Example:
        >>> from torchtasks.envs.control_suite.models import control_suite_spec
        >>> spec = control_suite_spec("swimmer", "swimmer6")
        >>> [body.name for body in spec.bodies][-2:]
        ['segment_3', 'segment_4']
        >>> control_suite_spec("quadruped", "walk").geom("floor").size.tolist()
        [10.0, 10.0, 0.5]
        >>> control_suite_spec("walker", "wlk")
        Traceback (most recent call last):
        ...
        ValueError: task: domain 'walker' has no task 'wlk'; did you mean 'walk'? (its tasks: 'stand', 'walk', 'run')
    """
    _check_task(domain, task)
    xml = _files().joinpath(f"{domain}.xml").read_text(encoding="utf-8")
    spec = mujoco.MjSpec.from_string(xml, include=_common_files())
    edit = _SPEC_EDITS.get((domain, task))
    if edit is not None:
        edit(spec)
    return spec


def _edit_row(model: mujoco.MjModel, edit: ModelEdit) -> int:
    if edit.field.startswith("dof_"):
        return int(model.joint(edit.name).dofadr[0])
    if edit.field.startswith("site_"):
        return model.site(edit.name).id
    return model.geom(edit.name).id


def control_suite_model(domain: str, task: str) -> mujoco.MjModel:
    """The compiled model of a Control Suite task, as dm_control's episodes of ``suite.load(domain, task)`` run on.

    It is :func:`control_suite_spec` compiled, with the task's :data:`FIXED_MODEL_EDITS` written into it as
    dm_control's reset writes them (finger spin's spinner damping 0.03, finger turn's and reacher's target sizes,
    the targets' transparency). Every numeric field then equals that of dm_control's model after a reset, except
    the targets' positions that a reset draws per episode.

    Args:
        domain: a domain of :data:`TASKS`, e.g. ``"finger"``.
        task: one of the domain's tasks, e.g. ``"spin"``.

    Raises ``TypeError`` or ``ValueError`` as :func:`control_suite_spec` does.

    Example:
        >>> from torchtasks.envs.control_suite.models import TASKS, control_suite_model
        >>> sum(len(tasks) for tasks in TASKS.values())
        30
        >>> model = control_suite_model("finger", "spin")
        >>> model.nq, model.nu, float(model.dof_damping[model.joint("hinge").dofadr[0]])
        (3, 2, 0.03)
        >>> model = control_suite_model("quadruped", "walk")
        >>> model.nq, model.nv, model.nu, model.na
        (23, 22, 12, 12)
        >>> control_suite_model("walkr", "walk")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        ValueError: domain: no Control Suite domain 'walkr'; did you mean 'walker'? (the domains: 'acrobot', ...)
    """
    _check_task(domain, task)
    # a copy of the one compiled model: compiling costs ~70 ms (95% of it MuJoCo drawing the skybox texture), a copy
    # ~20 ms of its 12 MB
    return copy.copy(_compiled(domain, task))


@functools.lru_cache(maxsize=32)
def _compiled(domain: str, task: str) -> mujoco.MjModel:
    spec = control_suite_spec(domain, task)
    with warnings.catch_warnings():
        # MuJoCo 4 deprecates cheetah.xml's settotalmass: the file is dm_control's, kept unchanged
        warnings.filterwarnings("ignore", message=_SETTOTALMASS_NOTICE, category=UserWarning)
        model = spec.compile()
    for edit in FIXED_MODEL_EDITS.get((domain, task), ()):
        values = getattr(model, edit.field)
        row = _edit_row(model, edit)
        if edit.column is None:
            values[row] = edit.value
        else:
            values[row, edit.column] = edit.value
    return model
