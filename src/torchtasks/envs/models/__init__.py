"""MuJoCo models written for torchtasks and shipped with the package (MJCF files, no meshes, no third-party files).

- ``"quadruped"``: a small legged robot (about 12 kg, 0.3 m high standing): a box torso on a free joint, four legs
  of three hinges (hip abduction, hip flexion, knee) driven by 12 position servos, spherical feet, a floor; an IMU
  site with gyro, accelerometer and velocimeter, the torso's orientation, a touch sensor per foot; the keyframe
  ``"home"`` stands, with ``ctrl`` at its joint angles. Timestep 5 ms (4 substeps = a 20 ms control step).
- ``"arm"``: a 2-link planar arm with two motors, a ``"fingertip"`` site and a target on two slide joints
  (``"target_x"``, ``"target_y"``) marked by the ``"target"`` site; keyframe ``"home"``.

Each file's header comment describes its bodies, joints, actuators, sensors and keyframes. This module only finds
the files: it does not import MuJoCo.
"""

from __future__ import annotations

import pathlib

from torchtasks._did_you_mean import did_you_mean

__all__ = ["MODEL_NAMES", "model_path"]

_FOLDER = pathlib.Path(__file__).resolve().parent

#: the names of the shipped models (the MJCF files of this folder, without ``.xml``)
MODEL_NAMES: tuple[str, ...] = tuple(sorted(path.stem for path in _FOLDER.glob("*.xml")))


def model_path(name: str) -> pathlib.Path:
    """The path of the shipped MJCF model called ``name`` (one of :data:`MODEL_NAMES`).

    Args:
        name: the model's name without the extension, e.g. ``"quadruped"`` or ``"arm"``.

    Raises ``TypeError`` when ``name`` is not a string and ``ValueError`` naming the shipped models when there is no
    model of that name.

    Example:
        >>> from torchtasks.envs.models import MODEL_NAMES, model_path
        >>> MODEL_NAMES
        ('arm', 'quadruped')
        >>> model_path("quadruped").name
        'quadruped.xml'
        >>> model_path("quadruped").is_file()
        True
        >>> model_path("quadrupd")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        ValueError: name: no shipped model 'quadrupd'; did you mean 'quadruped'? (the shipped models: 'arm', ...)
    """
    if not isinstance(name, str):
        raise TypeError(f"name must be a string naming a shipped model, got {type(name).__name__}")
    if name not in MODEL_NAMES:
        listed = ", ".join(repr(each) for each in MODEL_NAMES)
        hint = did_you_mean(name, MODEL_NAMES, cutoff=0.6)
        raise ValueError(f"name: no shipped model {name!r}{hint} (the shipped models: {listed})")
    return _FOLDER / f"{name}.xml"
