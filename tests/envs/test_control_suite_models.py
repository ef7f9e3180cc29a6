"""The Control Suite's models (torchtasks.envs.control_suite.models) are dm_control's, field for field.

dm_control's numbers come from dm_control itself: dm-control 1.0.50 on MuJoCo 3.17.0 in a reference venv, run once
for every task in one subprocess (``suite.load`` then ``reset``, every numeric field of the compiled model dumped).
Our model must equal dm_control's model after a reset in every numeric field both MuJoCo versions have (about 690:
sizes, the arrays of every object kind, names and their addresses, ``opt``, ``stat`` and ``vis``), except the
targets a reset draws per episode, where it keeps the file's value (that of the model ``suite.load`` compiled), and
the fields that differ between MuJoCo 3.17 and 4.0 whatever the model (listed below, with the reason). The shipped
files are dm_control's byte for byte (that an install ships them is checked by .ci/check_base_install.sh, which
installs a build of the checkout). The tests that need the reference venv skip with the reason when there is none.
"""

from __future__ import annotations

import inspect
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from repo_paths import ROOT  # noqa: E402
from torchtasks.envs._mujoco_log import quiet_model_loading, route_mujoco_warnings  # noqa: E402
from torchtasks.envs.control_suite.models import (  # noqa: E402
    FIXED_MODEL_EDITS,
    TASKS,
    control_suite_model,
    control_suite_spec,
)

#: one worker computes the module's models and dm_control's numbers once (``--dist loadgroup``)
pytestmark = [pytest.mark.mujoco, pytest.mark.xdist_group("control_suite_models")]

ALL_TASKS = [(domain, task) for domain, tasks in TASKS.items() for task in tasks]

#: the model values dm_control's reset draws anew at every episode (a task draws them; the model keeps the file's):
#: task -> (field, object kind, object name), from dm-control 1.0.50's initialize_episode
DRAWN = {
    ("finger", "turn_easy"): [("site_pos", "site", "target")],
    ("finger", "turn_hard"): [("site_pos", "site", "target")],
    ("fish", "swim"): [("geom_pos", "geom", "target")],
    ("manipulator", "bring_ball"): [("body_pos", "body", "target_ball"), ("body_quat", "body", "target_ball")],
    ("reacher", "easy"): [("geom_pos", "geom", "target")],
    ("reacher", "hard"): [("geom_pos", "geom", "target")],
    ("swimmer", "swimmer6"): [("geom_pos", "geom", "target"), ("light_pos", "light", "target_light")],
    ("swimmer", "swimmer15"): [("geom_pos", "geom", "target"), ("light_pos", "light", "target_light")],
}

#: the tasks whose XML dm_control edits (the others compile the domain's file as it is)
EDITED = {("quadruped", "walk"), ("quadruped", "run"), ("swimmer", "swimmer6"), ("swimmer", "swimmer15"),
          ("manipulator", "bring_ball")}  # fmt: skip
assert not EDITED & set(FIXED_MODEL_EDITS)  # so control_suite_model is the spec compiled for these

#: fields whose value depends on the MuJoCo version whatever the model (3.17 and 4.0 differ on SMALL_MODEL too,
#: which a test checks): the byte size of the model's buffer (4.0 has per-joint and per-tendon plastic and yield
#: fields, 3.17 flex_vertedge*), and the headlight's ``active`` (1 in 3.17, 2 in 4.0)
VERSION_FIELDS = ("nbuffer", "vis.headlight.active")
#: a model with one body, joint and geom
SMALL_MODEL = '<mujoco><worldbody><body><joint/><geom size="0.1"/></body></worldbody></mujoco>'

#: fields MuJoCo 3.17 and 4.0 round differently from the same XML: the cameras' orientation matrices at qpos0
#: (visual only; ``cam_quat``, which they are computed from, is equal). Measured: 1.11e-16 (quadruped), 5.55e-17
#: (fish, hopper, humanoid), 2.78e-17 (cheetah), 0 elsewhere. Under the same MuJoCo there is no difference at all
#: (test_dm_controls_xml_compiles_to_our_spec_under_the_same_mujoco)
ROUNDING = {"cam_mat0": 2.3e-16}

#: fields the comparison must include (a comparison that lost them would prove nothing)
REQUIRED = {
    "nq", "nv", "nu", "na", "nbody", "ngeom", "nsite", "nsensor", "njnt", "nsensordata", "opt.timestep",
    "opt.integrator", "opt.disableflags", "body_mass", "body_inertia", "body_pos", "body_quat", "geom_size",
    "geom_pos", "geom_friction", "site_size", "site_pos", "dof_damping", "dof_armature", "jnt_range", "qpos0",
    "actuator_ctrlrange", "actuator_gear", "actuator_dynprm", "sensor_adr", "sensor_type", "tendon_length0", "names",
    "name_bodyadr", "cam_pos",
}  # fmt: skip


def model_fields(model) -> dict:
    """Every numeric field of a compiled MjModel: its arrays and sizes, the numeric members of ``opt``, ``stat`` and
    ``vis`` (``"opt.timestep"``), ``names`` as bytes; arrays over 100000 values (textures) as their SHA-256.

    Runs in the reference venv too (its source is sent there), so it imports what it uses.
    """
    import hashlib

    import numpy as np

    fields = {}

    def collect(obj, prefix, depth):
        for name in dir(obj):
            if name.startswith("_"):
                continue
            try:
                value = getattr(obj, name)
            except Exception:
                continue
            if callable(value):
                continue
            if isinstance(value, np.ndarray):
                if value.dtype.kind not in "biuf":
                    continue
                if value.size > 100000:
                    digest = hashlib.sha256(value.dtype.str.encode())
                    digest.update(np.ascontiguousarray(value))
                    value = np.frombuffer(digest.digest(), np.uint8)
                fields[prefix + name] = value.copy()
            elif isinstance(value, (bool, int, float)):
                fields[prefix + name] = np.array(value)
            elif isinstance(value, bytes):
                fields[prefix + name] = np.frombuffer(value, np.uint8).copy()
            elif depth < 2 and type(value).__module__.startswith("mujoco"):
                collect(value, prefix + name + ".", depth + 1)

    collect(model, "", 0)
    return fields


#: run by the reference venv's python: argv[1] the tasks (JSON), argv[2] those whose model is also dumped as
#: suite.load returns it, before the reset (JSON), argv[3] the file to write the arrays' bytes to, one
#: after the other; prints their index (JSON: name, dtype, shape, offset); exits with 3 when dm_control does not
#: import there. (np.savez would take seconds to write and read the ~40000 arrays.)
REFERENCE_SCRIPT = """
import importlib.metadata, json, sys
try:
    import numpy as np
    import mujoco
    from dm_control import suite
    from dm_control.suite import common
except ImportError as error:
    print(f"dm_control does not import there: {type(error).__name__}: {error}", file=sys.stderr)
    sys.exit(3)

MODEL_FIELDS

# record the XML and the assets suite.load compiles (every domain's Physics is built by this class method)
from dm_control.mujoco import engine
compiled = []
from_xml_string = engine.Physics.from_xml_string.__func__


def recording(cls, xml_string, assets=None):
    compiled.append((xml_string, assets))
    return from_xml_string(cls, xml_string, assets=assets)


engine.Physics.from_xml_string = classmethod(recording)

tasks, loaded, out = json.loads(sys.argv[1]), json.loads(sys.argv[2]), sys.argv[3]
arrays = {
    "versions": np.array([mujoco.__version__, importlib.metadata.version("dm-control")]),
    "benchmarking": np.array([f"{domain}/{task}" for domain, task in suite.BENCHMARKING]),
}
for domain, task in tasks:
    compiled.clear()
    env = suite.load(domain, task, task_kwargs={"random": 0})
    (xml, assets), = compiled
    arrays[f"xml/{domain}/{task}"] = np.frombuffer(xml if isinstance(xml, bytes) else xml.encode(), np.uint8)
    for name, content in assets.items():
        arrays[f"asset/{domain}/{task}/{name}"] = np.frombuffer(content, np.uint8)
    if [domain, task] in loaded:
        for name, value in model_fields(env.physics.model.ptr).items():
            arrays[f"{domain}/{task}/loaded/{name}"] = value
    env.reset()
    for name, value in model_fields(env.physics.model.ptr).items():
        arrays[f"{domain}/{task}/reset/{name}"] = value
for name, value in model_fields(mujoco.MjModel.from_xml_string(SMALL_MODEL)).items():
    arrays[f"small/{name}"] = value
for domain in sorted({domain for domain, _ in tasks}):
    arrays[f"file/{domain}.xml"] = np.frombuffer(common.read_model(f"{domain}.xml"), np.uint8)
for name, content in common.ASSETS.items():
    arrays[f"file/{name[2:]}"] = np.frombuffer(content, np.uint8)
index, offset = [], 0
with open(out, "wb") as file:
    for name, value in arrays.items():
        if value.dtype.kind == "U":
            value = np.frombuffer("\\n".join(value.tolist()).encode(), np.uint8)
            name = "lines/" + name
        index.append([name, value.dtype.str, list(value.shape), offset])
        file.write(value.tobytes())  # C order
        offset += value.nbytes
print(json.dumps(index))
""".replace("MODEL_FIELDS", inspect.getsource(model_fields)).replace("SMALL_MODEL", repr(SMALL_MODEL))


def dm_control_python() -> str:
    """The python of the dm_control reference venv (dm-control 1.0.50, MuJoCo 3.17.0); skips the test if none.

    ``TORCHTASKS_DM_CONTROL_PYTHON``, else ``./.venv-dmc/bin/python``, else ``/tmp/venv-dmc-probe/bin/python``.
    """
    variable = os.environ.get("TORCHTASKS_DM_CONTROL_PYTHON")
    if variable:
        if not os.access(variable, os.X_OK):
            pytest.skip(f"TORCHTASKS_DM_CONTROL_PYTHON={variable!r} is not an executable python")
        return variable
    for candidate in (Path.cwd() / ".venv-dmc" / "bin" / "python", Path("/tmp/venv-dmc-probe/bin/python")):
        if os.access(candidate, os.X_OK):
            return str(candidate)
    pytest.skip(
        "no dm_control reference venv (set TORCHTASKS_DM_CONTROL_PYTHON, or: python -m venv .venv-dmc && "
        ".venv-dmc/bin/pip install mujoco==3.17.0 dm-control==1.0.50)"
    )


@pytest.fixture(scope="module")
def ours() -> dict[tuple[str, str], mujoco.MjModel]:
    return {(domain, task): control_suite_model(domain, task) for domain, task in ALL_TASKS}


@pytest.fixture(scope="module")
def reference(request, tmp_path_factory) -> dict[str, np.ndarray]:
    """dm_control's numbers: every task's fields (``"<domain>/<task>/<loaded|reset>/<field>"``), the XML and assets
    ``suite.load`` compiles (``"xml/<domain>/<task>"``, ``"asset/<domain>/<task>/<name>"``), dm_control's files
    (``"file/<name>"``), ``SMALL_MODEL``'s fields (``"small/<field>"``), its versions and BENCHMARKING list."""
    python = dm_control_python()
    out = tmp_path_factory.mktemp("dm_control") / "fields.bin"
    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    env["MUJOCO_GL"] = "disable"
    process = subprocess.Popen(
        [python, "-c", REFERENCE_SCRIPT, json.dumps(ALL_TASKS), json.dumps([*DRAWN, *FIXED_MODEL_EDITS]), str(out)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    request.getfixturevalue("ours")  # our models compile while dm_control loads its own
    stdout, stderr = process.communicate(timeout=600)
    if process.returncode == 3:
        pytest.skip(f"the reference venv {python}: {stderr.strip()}")
    assert process.returncode == 0, f"the reference script failed in {python}:\n{stderr}"
    blob = out.read_bytes()
    fields: dict[str, np.ndarray] = {}
    for name, dtype, shape, offset in json.loads(stdout):
        value = np.frombuffer(blob, dtype, count=int(np.prod(shape)), offset=offset).reshape(shape)
        if name.startswith("lines/"):
            name, value = name[len("lines/") :], np.array(value.tobytes().decode().split("\n"))
        fields[name] = value
    assert fields["versions"].tolist() == ["3.17.0", "1.0.50"], f"{python} is not mujoco 3.17.0 + dm-control 1.0.50"
    return fields


def _task_fields(reference: dict[str, np.ndarray], prefix: str) -> dict[str, np.ndarray]:
    return {key[len(prefix) :]: value for key, value in reference.items() if key.startswith(prefix)}


def _differences(got: dict, expected: dict) -> tuple[list[str], float]:
    """The fields of ``got`` that differ from ``expected`` (the fields both have), and the largest float difference."""
    shared = set(got) & set(expected)
    missing = REQUIRED - shared
    assert not missing and len(shared) > 600, (sorted(missing), len(shared))
    differences, largest = [], 0.0
    for name in sorted(shared - set(VERSION_FIELDS)):
        a, b = got[name], expected[name]
        if a.shape != b.shape:
            differences.append(f"{name}: shape {a.shape} vs {b.shape}")
            continue
        if a.dtype.kind == "f" and a.size:
            largest = max(largest, float(np.abs(a - b).max()))
        if name in ROUNDING:
            if not np.allclose(a, b, rtol=0.0, atol=ROUNDING[name]):
                differences.append(f"{name}: max |difference| {np.abs(a - b).max():.3g}")
        elif not np.array_equal(a, b):
            where = np.flatnonzero(a.ravel() != b.ravel())
            first = where[0]
            differences.append(
                f"{name}: {where.size} values differ, first [{first}]: {a.flat[first]} vs {b.flat[first]}"
            )
    return differences, largest


def test_the_tasks_are_dm_controls_benchmarking_and_quadruped_walk_run(reference):
    benchmarking = [tuple(name.split("/")) for name in reference["benchmarking"].tolist()]
    assert len(benchmarking) == 28
    assert ALL_TASKS == [*benchmarking, ("quadruped", "walk"), ("quadruped", "run")]


@pytest.mark.slow  # its fixtures: our 30 models and dm_control's (a subprocess), about 5 s
def test_every_task_is_dm_controls_model_after_a_reset(ours, reference):
    """Every shared numeric field equals dm_control's after ``reset`` (the drawn targets: after ``suite.load``)."""
    problems, largest = {}, 0.0
    for domain, task in ALL_TASKS:
        model = ours[(domain, task)]
        reset = _task_fields(reference, f"{domain}/{task}/reset/")
        loaded = _task_fields(reference, f"{domain}/{task}/loaded/")
        expected = dict(reset)
        for field, kind, name in DRAWN.get((domain, task), ()):
            row = getattr(model, kind)(name).id
            # the reset drew it (so this exemption hides no fixed edit), and our model keeps the file's value
            assert not np.array_equal(reset[field][row], loaded[field][row]), (domain, task, field)
            expected[field] = reset[field].copy()
            expected[field][row] = loaded[field][row]
        differences, task_largest = _differences(model_fields(model), expected)
        largest = max(largest, task_largest)
        if differences:
            problems[f"{domain}-{task}"] = differences
    assert not problems, problems
    assert largest <= max(ROUNDING.values())


def test_the_spec_compiles_to_dm_controls_model_as_suite_load_returns_it(reference):
    """Before the fixed edits (the tasks that have some): :func:`control_suite_spec` compiled is ``suite.load``'s."""
    for domain, task in FIXED_MODEL_EDITS:
        model = control_suite_spec(domain, task).compile()
        differences, _ = _differences(model_fields(model), _task_fields(reference, f"{domain}/{task}/loaded/"))
        assert not differences, (domain, task, differences)


def test_dm_controls_xml_compiles_to_our_spec_under_the_same_mujoco(ours, reference):
    """Compiled by the same MuJoCo (ours), the XML and assets dm_control's ``suite.load`` compiles give the model of
    :func:`control_suite_spec` in every numeric field, bit for bit, none exempt: the edits made on the spec instead of
    dm_control's lxml (deletions, the generated swimmer) leave nothing different, names and their order included.

    The XML of the other tasks is the shipped file itself, byte for byte; of those, cheetah (whose file MuJoCo 4
    warns about) is compiled too. (Each compile costs about 70 ms, most of it generating the skybox texture.)
    """
    route_mujoco_warnings()  # cheetah.xml's settotalmass notice: a Python warning quiet_model_loading hides
    folder = ROOT / "src" / "torchtasks" / "envs" / "models" / "dm_control"
    for domain, task in ALL_TASKS:
        prefix = f"asset/{domain}/{task}/"
        assets = {key[len(prefix) :]: value.tobytes() for key, value in reference.items() if key.startswith(prefix)}
        assert sorted(assets) == ["./common/materials.xml", "./common/skybox.xml", "./common/visual.xml"]
        xml = reference[f"xml/{domain}/{task}"].tobytes()
        assert (xml == (folder / f"{domain}.xml").read_bytes()) == ((domain, task) not in EDITED), (domain, task)
        if (domain, task) not in {*EDITED, ("cheetah", "run")}:
            continue
        with quiet_model_loading():
            theirs = mujoco.MjModel.from_xml_string(xml.decode(), assets)
        a, b = model_fields(ours[(domain, task)]), model_fields(theirs)
        assert a.keys() == b.keys() and len(a) > 600
        differing = [name for name in a if a[name].shape != b[name].shape or not np.array_equal(a[name], b[name])]
        assert not differing, (domain, task, differing)


def test_the_version_fields_differ_for_any_model(reference):
    small = model_fields(mujoco.MjModel.from_xml_string(SMALL_MODEL))
    for name in VERSION_FIELDS:
        assert not np.array_equal(small[name], reference[f"small/{name}"]), name


def test_the_shipped_files_are_dm_controls(reference):
    files = {key[len("file/") :]: value.tobytes() for key, value in reference.items() if key.startswith("file/")}
    assert len(files) == len(TASKS) + 3
    for name, content in files.items():
        shipped = ROOT / "src" / "torchtasks" / "envs" / "models" / "dm_control" / name
        assert shipped.read_bytes() == content, name


def test_bad_names_are_refused_with_the_closest():
    for build in (control_suite_spec, control_suite_model):
        with pytest.raises(ValueError, match=r"domain: no Control Suite domain 'cheeta'; did you mean 'cheetah'\?"):
            build("cheeta", "run")
        with pytest.raises(ValueError, match=r"domain: no Control Suite domain 'dog' \(the domains: 'acrobot', "):
            build("dog", "run")
        with pytest.raises(ValueError, match=r"task: domain 'swimmer' has no task 'swimmer7'; did you mean "):
            build("swimmer", "swimmer7")
        # a task of dm_control's that is not a preset here
        with pytest.raises(ValueError, match=r"domain 'quadruped' has no task 'fetch' \(its tasks: 'walk', 'run'\)"):
            build("quadruped", "fetch")
        with pytest.raises(TypeError, match="domain must be a string"):
            build(None, "run")  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="task must be a string"):
            build("cheetah", 0)  # type: ignore[arg-type]
