"""A MuJoCo model from what a user has (a model, a spec, a file, an XML string) and its objects by name.

:func:`load_model` turns an ``mujoco.MjModel``, an ``mujoco.MjSpec``, the path of an MJCF file or an MJCF string into
a compiled model, answering a model that does not compile with MuJoCo's message and the file. :func:`object_id`
finds a named body, joint, geom, site, sensor, actuator or keyframe, and answers a miss with the closest names of
that kind. The batched env, its readings, its actions and its resets read names through these two.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Literal, Union

from torchtasks._did_you_mean import closest
from torchtasks._optional import missing_extra

try:
    import mujoco
except ImportError as _error:
    raise missing_extra("mujoco", "torchtasks.envs.mujoco_model", _error) from _error

from torchtasks.envs._mujoco_log import quiet_model_loading

__all__ = ["ModelSource", "ObjectKind", "load_model", "model_label", "object_id", "object_names"]

#: what a model can be given as
ModelSource = Union[mujoco.MjModel, mujoco.MjSpec, str, "os.PathLike[str]"]

#: the kinds of named objects, and the MjModel count and ``mjtObj`` of each
ObjectKind = Literal["body", "joint", "geom", "site", "sensor", "actuator", "keyframe", "tendon", "camera"]
_KINDS: dict[str, tuple[str, int]] = {
    "body": ("nbody", int(mujoco.mjtObj.mjOBJ_BODY)),
    "joint": ("njnt", int(mujoco.mjtObj.mjOBJ_JOINT)),
    "geom": ("ngeom", int(mujoco.mjtObj.mjOBJ_GEOM)),
    "site": ("nsite", int(mujoco.mjtObj.mjOBJ_SITE)),
    "sensor": ("nsensor", int(mujoco.mjtObj.mjOBJ_SENSOR)),
    "actuator": ("nu", int(mujoco.mjtObj.mjOBJ_ACTUATOR)),
    "keyframe": ("nkey", int(mujoco.mjtObj.mjOBJ_KEY)),
    "tendon": ("ntendon", int(mujoco.mjtObj.mjOBJ_TENDON)),
    "camera": ("ncam", int(mujoco.mjtObj.mjOBJ_CAMERA)),
}


def _is_xml(text: str) -> bool:
    return text.lstrip().startswith("<")


def model_label(source: object) -> str:
    """A short name of a model source for messages: the file, ``"<MJCF string>"``, ``"<MjSpec>"`` or ``"<MjModel>"``.

    Example:
        >>> model_label("robot.xml"), model_label("<mujoco/>")
        ("'robot.xml'", '<MJCF string>')
    """
    if isinstance(source, (str, os.PathLike)):
        text = os.fspath(source)
        return "<MJCF string>" if _is_xml(text) else repr(text)
    return f"<{type(source).__name__}>"


def load_model(source: object) -> mujoco.MjModel:
    """Compile ``source`` into a ``mujoco.MjModel``.

    Args:
        source: an ``MjModel`` (returned as is), an ``MjSpec`` (compiled), the path of an MJCF (or MJB) file, or an
            MJCF string (any string whose first character other than whitespace is ``<``).

    Raises ``TypeError`` for anything else and ``ValueError`` for a file that does not exist or a model that does
    not compile, with MuJoCo's message and the file.

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model
        >>> model = load_model('<mujoco><worldbody><body><joint/><geom size="0.1"/></body></worldbody></mujoco>')
        >>> model.nq, model.nbody
        (1, 2)
        >>> load_model("<mujoco><worldbody><geom/></worldbody></mujoco>")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        ValueError: the model <MJCF string> does not compile: ...
    """
    if isinstance(source, mujoco.MjModel):
        return source
    label = model_label(source)
    try:
        if isinstance(source, mujoco.MjSpec):
            with quiet_model_loading():
                return source.compile()
        if isinstance(source, (str, os.PathLike)):
            text = os.fspath(source)
            if _is_xml(text):
                with quiet_model_loading():
                    return mujoco.MjModel.from_xml_string(text)
            if not os.path.isfile(text):
                raise ValueError(
                    f"model must be an MjModel, an MjSpec, an MJCF string or the path of a model file; "
                    f"no file {text!r} (from {os.getcwd()!r})"
                )
            with quiet_model_loading():
                if text.endswith(".mjb"):
                    return mujoco.MjModel.from_binary_path(text)
                return mujoco.MjModel.from_xml_path(text)
    except ValueError as error:
        if str(error).startswith("model must be"):
            raise
        raise ValueError(f"the model {label} does not compile: {error}") from None
    raise TypeError(
        f"model must be a mujoco.MjModel, a mujoco.MjSpec, an MJCF string or the path of a model file, "
        f"got {type(source).__name__}"
    )


def _check_kind(kind: object) -> tuple[str, int]:
    if kind not in _KINDS:
        raise ValueError(f"kind must be one of {sorted(_KINDS)}, got {kind!r}")
    return _KINDS[kind]  # type: ignore[index]


def object_names(model: mujoco.MjModel, kind: ObjectKind) -> list[str]:
    """The names of the model's objects of ``kind`` in id order (``""`` for an unnamed one).

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model, object_names
        >>> model = load_model('<mujoco><worldbody><body name="a"><joint name="j"/><geom size="1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> object_names(model, "body"), object_names(model, "joint")
        (['world', 'a'], ['j'])
    """
    count, obj = _check_kind(kind)
    return [mujoco.mj_id2name(model, obj, i) or "" for i in range(getattr(model, count))]


def object_id(model: mujoco.MjModel, kind: ObjectKind, name: object, argument: str) -> int:
    """The id of the model's ``kind`` named ``name``; else a ``ValueError`` naming ``argument`` and the close names.

    Args:
        model: the compiled model.
        kind: ``"body"``, ``"joint"``, ``"geom"``, ``"site"``, ``"sensor"``, ``"actuator"``, ``"keyframe"``,
            ``"tendon"`` or ``"camera"``.
        name: the object's name.
        argument: what the caller calls the name, for the message (``"joint_pos joints"``).

    Example:
        >>> from torchtasks.envs.mujoco_model import load_model, object_id
        >>> model = load_model('<mujoco><worldbody><body name="thigh"><joint name="hip"/><geom size="1"/></body>'
        ...                    '</worldbody></mujoco>')
        >>> object_id(model, "joint", "hip", "joints")
        0
        >>> object_id(model, "body", "thig", "body")
        Traceback (most recent call last):
        ...
        ValueError: body: the model has no body 'thig'; did you mean 'thigh'? (its bodies: 'world', 'thigh')
    """
    if not isinstance(name, str):
        raise TypeError(f"{argument} must name a {kind} with a string, got {name!r}")
    _, obj = _check_kind(kind)
    found = mujoco.mj_name2id(model, obj, name)
    if found >= 0:
        return int(found)
    names = [each for each in object_names(model, kind) if each]
    if not names:
        raise ValueError(f"{argument}: the model has no named {kind}, so none called {name!r}")
    near = closest(name, names, n=3, cutoff=0.6)
    hint = "" if not near else "; did you mean " + _either(near) + "?"
    listed = _listing(names)
    plural = "bodies" if kind == "body" else f"{kind}s"
    raise ValueError(f"{argument}: the model has no {kind} {name!r}{hint} (its {plural}: {listed})")


def _either(names: Sequence[str]) -> str:
    quoted = [repr(name) for name in names]
    return quoted[0] if len(quoted) == 1 else ", ".join(quoted[:-1]) + " or " + quoted[-1]


def _listing(names: Sequence[str], limit: int = 12) -> str:
    shown = ", ".join(repr(name) for name in names[:limit])
    return shown if len(names) <= limit else f"{shown}, ... ({len(names)} in all)"
