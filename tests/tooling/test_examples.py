"""The example scripts run end to end with ``--quick`` and print what they promise.

Each example runs as a subprocess (``sys.executable``), as a user would run it, from a fresh empty
directory and with its default outputs: :func:`run_quick` also checks that it writes nothing there
but ``runs/<example name>/`` (see ``test_examples_write_under_runs.py``). The Ray example starts (and
shuts down) its own local Ray cluster; the MuJoCo example needs the ``mujoco`` extra.

Every script's ``--help`` runs in one interpreter (:func:`help_outputs`): each script as ``__main__`` with
``sys.argv = [script, "--help"]``, as ``python examples/<script> --help`` runs it, one after the other. A fresh
interpreter per script cost an import of torch and TorchRL each (~6 s of CPU apiece on the 2-core machine); the
``--quick`` runs below still start every script in an interpreter of its own.
"""

from __future__ import annotations

import importlib.util
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from example_runs import EXAMPLES, run_quick

# the ``--quick`` runs go to one worker with those of test_examples_training.py (group "examples"): they fork from
# one server (example_runs.py) there; the ``--help`` checks share one interpreter (a module-scoped fixture), so they
# form a group of their own ("examples_help": this mark and theirs), which the other worker may take
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("examples")]


SPHINX_MARKUP = ("``", ":class:", ":func:", ":meth:", ":mod:", ":attr:")
EPILOG = "Details: the module docstring of this script. TorchRL's INFO logs: RL_LOGGING_LEVEL=INFO."


def run_example(name: str, cwd: Path, *args: str, timeout: float = 180.0, fresh: bool = False) -> str:
    """Run ``examples/<name> --quick *args`` from the empty folder ``cwd``; return its stdout (:func:`run_quick`;
    ``fresh``: in a fresh interpreter, not a child of the fork server).

    Also checks that TorchRL's INFO logs are quiet (the examples set the ``torchrl`` logger to WARNING).
    """
    result = run_quick(name, cwd, *args, timeout=timeout, fresh=fresh)
    assert_no_torchrl_info(result.stdout + result.stderr)
    return result.stdout


def assert_no_torchrl_info(output: str) -> None:
    """No ``[torchrl][INFO]`` line (e.g. ``Initialized LazyTensorStorage``) in an example's output."""
    lines = [line for line in output.splitlines() if "[torchrl][INFO]" in line]
    assert not lines, f"TorchRL INFO logs in the example's output: {lines[:3]}"


SCRIPTS = sorted(path.name for path in EXAMPLES.glob("[!_]*.py"))

#: runs ``<examples>/<script> --help`` for each script named on its command line, in its current directory, as
#: ``__main__`` (the scripts' folder first on ``sys.path``, as for ``python <script>``): a marker line before each
#: script's output on both streams, then a JSON object with each script's exit status and the entries that appeared
#: in the current directory while it ran
HELP_DRIVER = """
import json, os, runpy, sys, traceback
folder, scripts = sys.argv[1], sys.argv[2:]
sys.path[0] = folder  # the script's folder in place of -c's current directory, as for python <script>
results = {}
for script in scripts:
    marker = "\\0" + script + "\\0"
    print(marker, flush=True)
    print(marker, file=sys.stderr, flush=True)
    before = set(os.listdir("."))
    sys.argv = [os.path.join(folder, script), "--help"]
    status = 0
    try:
        runpy.run_path(sys.argv[0], run_name="__main__")
    except SystemExit as exit:
        status = exit.code if isinstance(exit.code, int) else (exit.code is not None)
    except BaseException:
        traceback.print_exc()
        status = 1
    sys.stdout.flush()
    sys.stderr.flush()
    results[script] = {"status": status, "written": sorted(set(os.listdir(".")) - before)}
print("\\0RESULTS\\0" + json.dumps(results), flush=True)
print("\\0RESULTS\\0", file=sys.stderr, flush=True)
"""


def _per_script(stream: str) -> dict[str, str]:
    """What each script wrote to ``stream``: the driver starts each script's part with a line ``\\0<script>\\0``
    (and ends the last one with ``\\0RESULTS\\0``)."""
    pieces = stream.split("\0")
    assert pieces[0] == "", f"output before the first script's --help: {pieces[0][-3000:]}"
    return {name: text.removeprefix("\n") for name, text in zip(pieces[1::2], pieces[2::2], strict=True)}


@pytest.fixture(scope="module")
def help_outputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict]:
    """Per script: ``status``, ``stdout``, ``stderr`` and ``written`` (new entries in the current directory) of its
    ``--help``, all scripts run by :data:`HELP_DRIVER` in one interpreter from an empty directory."""
    cwd = tmp_path_factory.mktemp("help")
    command = [sys.executable, "-c", HELP_DRIVER, str(EXAMPLES), *SCRIPTS]
    result = subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 0, f"the --help driver failed:\n{result.stderr[-3000:]}"
    stdouts, stderrs = _per_script(result.stdout), _per_script(result.stderr)
    outputs = json.loads(stdouts.pop("RESULTS"))
    stderrs.pop("RESULTS")
    assert list(outputs) == SCRIPTS and list(stdouts) == SCRIPTS and list(stderrs) == SCRIPTS
    for script in SCRIPTS:
        outputs[script].update(stdout=stdouts[script], stderr=stderrs[script])
    return outputs


@pytest.mark.xdist_group("help")
@pytest.mark.parametrize("script", SCRIPTS)
def test_help_is_short_plain_and_shows_defaults(script: str, help_outputs: dict[str, dict]) -> None:
    """``--help``: the docstring's first paragraph, then every option with a description and its default, in 40 x 100.

    One format everywhere: ``(default: 0 1 2)`` (``_cli.default_text``), short metavars, the same footer.
    """
    result = help_outputs[script]
    assert result["status"] == 0, result["stderr"]
    assert not result["written"], f"--help wrote {result['written']}"
    text = result["stdout"]
    lines = text.splitlines()
    assert len(lines) <= 40, f"{len(lines)} lines:\n{text}"
    wide = [line for line in lines if len(line) > 100]
    assert not wide, f"lines over 100 columns: {wide}"
    assert not [mark for mark in SPHINX_MARKUP if mark in text], text
    assert "[torchrl][INFO]" not in text + result["stderr"]
    assert lines[-1] == EPILOG, "the footer differs from the other examples'"
    options = text.split("options:", 1)[1].split("\n\n", 1)[0]
    for block in re.split(r"\n(?=  -)", options.strip("\n")):
        # the invocation (``--name METAVAR [METAVAR ...]``, single spaces), then the help after 2+ spaces or a new line
        match = re.fullmatch(r"\s*(\S+(?: \S+)*?)(?: {2,}|\n\s+)(.+)", block, flags=re.DOTALL)
        assert match is not None, f"an option without a description:\n{block}"
        invocation, help_text = match.group(1), " ".join(match.group(2).split())
        metavars = [
            word.strip("[],.") for word in invocation.split() if not word.startswith("-") and word.strip("[],.")
        ]
        short = [name for name in metavars if not re.fullmatch(r"[A-Z]{1,7}", name)]
        assert not short, f"metavars should be short (N, X, DIR, PATH, NAME, ID): {short} in {invocation!r}"
        described = help_text.split("(default: ", 1)[0].strip()
        assert re.search(r"[a-z]{2}", described), f"{invocation}: no description besides the default: {help_text!r}"
        defaults = re.findall(r"\(default: ([^)]*)\)", help_text)
        assert help_text.count("default") == len(defaults), f"{invocation}: a default not as '(default: ...)'"
        if metavars:  # an option that takes a value says its default
            assert len(defaults) == 1, f"{invocation}: no '(default: ...)' in {help_text!r}"
        for default in defaults:
            assert not re.search(r"[\[\]'\"]", default), f"{invocation}: a Python repr as default: {default!r}"
            assert not re.search(r"\d{5}", default), f"{invocation}: {default!r} without thousands separators"


def test_default_text_is_the_one_format() -> None:
    """``_cli.default_text``: lists space-separated, numbers from 10,000 on with separators, no reprs."""
    spec = importlib.util.spec_from_file_location("_cli", EXAMPLES / "_cli.py")
    cli = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cli)
    assert cli.default_text([0, 1, 2]) == "(default: 0 1 2)"
    assert cli.default_text(("her", "plain")) == "(default: her plain)"
    assert cli.default_text(2_097_152) == "(default: 2,097,152)" and cli.default_text(8192) == "(default: 8192)"
    assert cli.default_text(3e-4) == "(default: 0.0003)" and cli.default_text(30.0) == "(default: 30)"
    assert cli.default_text(Path("runs/x")) == "(default: runs/x)"
    assert cli.default_text(32, "8 with --quick") == "(default: 32; 8 with --quick)"
    assert cli.default_text("80%") == "(default: 80%%)"  # argparse %-formats the help


def test_progress_bars_count_frames() -> None:
    """Every example's progress bar is ``_cli.frame_bar`` (unit ``frame``, scaled): no example builds its own."""
    own = [path.name for path in EXAMPLES.glob("*.py") if path.name != "_cli.py" and "tqdm" in path.read_text()]
    assert not own, f"examples with their own tqdm bar (use _cli.frame_bar): {own}"


def _number(pattern: str, text: str) -> float:
    match = re.search(pattern, text, flags=re.MULTILINE)
    assert match is not None, f"no line matching {pattern!r} in:\n{text}"
    return float(match.group(1))


def test_quickstart(tmp_path: Path) -> None:
    out = run_example("quickstart.py", tmp_path)
    assert "8 envs x 50 steps" in out
    for label in ("step reward (track + effort)", "final reward (+100 on success)", "track term", "effort term"):
        assert re.search(rf"mean per step, {re.escape(label)}\s*: [+-]\d", out), label
    assert "successes:" in out and "mean episode reward of finished episodes" in out


@pytest.mark.ray
@pytest.mark.multiprocess
def test_distributed_ray(tmp_path: Path) -> None:
    """The default: two Ray actors, each with 8 batched Hopper envs (BatchedMujocoEnv) and random actions."""
    pytest.importorskip("ray")
    if importlib.util.find_spec("mujoco") is None or importlib.util.find_spec("gymnasium") is None:
        pytest.skip("needs the mujoco extra (mujoco, gymnasium)")
    # Ray start-up (cluster, then two actors importing torch) takes most of the time on a loaded 2-core machine
    out = run_example("distributed_ray.py", tmp_path, timeout=300.0, fresh=True)  # Ray's client is not forked
    assert "Ray collector: 2 workers x 8 Hopper-v5 envs (BatchedMujocoEnv)" in out
    assert _number(r"^frames collected: (\d+)", out) == 2400
    episodes = _number(r"^episodes ended: (\d+)", out)
    # random actions: Hopper falls (a task failure) long before the 1000-step limit
    assert episodes > 0 and _number(r"failures: (\d+)", out) == episodes
    assert "successes" not in out  # the locomotion task cannot succeed: no count of it
    assert _number(r"truncations: (\d+)", out) == 0
    for term in ("forward", "ctrl", "survive"):  # no step/final pair: the preset pays no final reward
        assert re.search(rf"^\s+{term}\s+[+-]\d+\.\d+$", out, flags=re.MULTILINE), term
    assert _number(r"^\s+survive\s+([+-]\d+\.\d+)$", out) > 0  # healthy_reward 1 per healthy step
    assert _number(r"max abs difference (\S+)$", out) == 0.0


def test_distributed_ray_pendulum_pieces() -> None:
    """``--env pendulum`` without Ray: the worker's env, the controller and the driver's statistics, in-process."""
    import torch
    from torchrl.collectors import Collector

    pytest.importorskip("ray")
    spec = importlib.util.spec_from_file_location("distributed_ray", EXAMPLES / "distributed_ray.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    threads = torch.get_num_threads()
    stats = module.EpisodeStats(module.make_offline_transform("pendulum"))
    collector = Collector(
        module.make_env("pendulum", 8, 0), module.make_policy("pendulum"), frames_per_batch=800, total_frames=2400
    )
    try:
        for batch in collector:
            stats.update(batch)
    finally:
        collector.shutdown()
        torch.set_num_threads(threads)
    assert stats.frames == 2400 and stats.successes > 0 and stats.failures == 0
    assert stats.episodes == stats.successes + stats.truncations
    # the controller only ends episodes by success, each paid +100 once
    assert stats.terms["final"] == pytest.approx(100.0 * stats.successes)
    assert stats.max_offline_diff == 0.0
    assert f"successes: {stats.successes}, " in stats.report()  # the swing-up task defines success
    assert module.make_policy("Hopper-v5") is None
    with pytest.raises(ValueError, match="env_id"):
        module.make_offline_transform("CartPole-v1")


def test_her_relabel(tmp_path: Path) -> None:
    out = run_example("her_relabel.py", tmp_path)
    assert "relabelled rewards equal the task's reward for the new goal: 256 transitions checked" in out
    assert "per-env goal sampling" in out
    before = _number(r"successful transitions before relabelling:\s+([\d.]+)%", out)
    after = _number(r"successful transitions after relabelling:\s+([\d.]+)%", out)
    assert after > before  # hindsight goals are reached far more often than the sampled ones


@pytest.mark.mujoco
def test_mujoco_locomotion(tmp_path: Path) -> None:
    if importlib.util.find_spec("mujoco") is None or importlib.util.find_spec("gymnasium") is None:
        pytest.skip("needs the mujoco extra (mujoco, gymnasium)")
    out = run_example("mujoco_locomotion.py", tmp_path)
    assert "HalfCheetah-v5: 300 frames" in out
    for term in ("forward", "ctrl", "reward"):
        assert re.search(rf"^\| {term} \|", out, flags=re.MULTILINE), term
    assert _number(r"largest difference to Gymnasium's info terms over 300 steps: (\S+)$", out) < 1e-5
    assert "RewardSum episode sums match the per-step terms summed by hand" in out


def test_potential_shaping(tmp_path: Path) -> None:
    out = run_example("potential_shaping.py", tmp_path)
    output = tmp_path / "runs" / "potential_shaping" / "quick"  # the default --output of a --quick run
    assert "frame budget 1,024 per run" in out
    for label in ("sparse", "sparse + shaping"):
        for seed in (0, 1):
            assert re.search(rf"^\s*{re.escape(label)}, seed {seed}: 80% (after|not reached)", out, re.MULTILINE)
    experiment = json.loads((output / "potential_shaping.json").read_text())
    assert set(experiment["variants"]) == {"sparse", "shaped"}
    assert f"γ = {experiment['config']['gamma']:g} (the PPO discount)" in experiment["shaping"]
    for variant in experiment["variants"].values():
        assert [run["seed"] for run in variant["runs"]] == [0, 1]
        for run in variant["runs"]:
            assert run["total_frames"] == experiment["frame_budget"] == 1024  # the same budget for every run
            assert all(0.0 <= point["eval_success_rate"] <= 1.0 for point in run["curve"])
        mean = variant["mean_curve"]
        assert len(mean["frames"]) == len(mean["eval_success_rate"]) == 2
        for i, rate in enumerate(mean["eval_success_rate"]):
            per_seed = [run["curve"][i]["eval_success_rate"] for run in variant["runs"]]
            assert rate == pytest.approx(sum(per_seed) / len(per_seed))
    assert (output / "potential_shaping.png").stat().st_size > 0


def test_goal_reaching(tmp_path: Path) -> None:
    import json

    out = run_example("goal_reaching.py", tmp_path)
    output = tmp_path / "runs" / "goal_reaching" / "quick"  # the default --output of a --quick run
    for variant in ("her", "plain"):
        assert re.search(
            rf"^{variant}, seed 0: 90% (after [\d,]+ frames|not reached); final success rate", out, re.MULTILINE
        )
    experiment = json.loads((output / "goal_reaching.json").read_text())
    assert set(experiment["variants"]) == {"her", "plain"}
    for variant in experiment["variants"].values():
        (run,) = variant["runs"]
        assert run["seed"] == 0 and run["updates"] > 0  # the warm-up ended and TD3 trained
        assert run["curve"][0]["frames"] == 0
        assert all(0.0 <= point["eval_success_rate"] <= 1.0 for point in run["curve"])
        assert variant["frames_to_target"] == [run["frames_to_target"]]
    assert (output / "goal_reaching.png").stat().st_size > 0


def test_curriculum_reaching(tmp_path: Path) -> None:
    out = run_example("curriculum_reaching.py", tmp_path)
    output = tmp_path / "runs" / "curriculum_reaching" / "quick"  # the default --output of a --quick run
    for variant in ("curriculum", "baseline"):
        assert re.search(rf"^{variant}, seed 0: 80% (after [\d,]+ frames|not reached)", out, re.MULTILINE)
    experiment = json.loads((output / "curriculum_reaching.json").read_text())
    assert set(experiment["variants"]) == {"curriculum", "baseline"}
    budget = experiment["config"]["total_frames"]
    batches = budget // (experiment["config"]["num_envs"] * experiment["config"]["rollout_steps"])
    runs = {variant: run for variant, (run,) in experiment["variants"].items()}  # one seed each
    for run in runs.values():
        assert run["seed"] == 0 and run["total_frames"] == budget
        frames = [point["frames"] for point in run["curve"]]
        assert frames[0] == 0 and frames[-1] == budget and frames == sorted(frames)
        assert all(0.0 <= point["eval_success_rate"] <= 1.0 for point in run["curve"])
        assert len(run["train_curve"]) == batches
    # the same evaluation set: the two runs start from the same policy (seed 0) and score the same at frame 0
    assert runs["curriculum"]["curve"][0] == runs["baseline"]["curve"][0]
    # the curriculum's effort weight ramps to the full weight by ramp_frames; the baseline has it from the start
    full, ramp = experiment["config"]["effort_weight"], experiment["config"]["ramp_frames"]
    for point in runs["curriculum"]["train_curve"]:
        assert point["effort_weight"] == pytest.approx(full * min(1.0, point["frames"] / ramp), rel=1e-5)
        assert len(point["level_fractions"]) == len(experiment["env"]["goal_half_widths"])
        assert sum(point["level_fractions"]) == pytest.approx(1.0)
    assert all(point["effort_weight"] == full for point in runs["baseline"]["train_curve"])
    assert "level_fractions" not in runs["baseline"]["train_curve"][0]
    if importlib.util.find_spec("matplotlib") is not None:
        assert (output / "curriculum_reaching.png").stat().st_size > 0
