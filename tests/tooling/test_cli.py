"""The ``torchtasks`` command: every subcommand, its help, exit code and outputs.

Most calls go through ``torchtasks.cli.main([...])`` in-process; one subprocess checks that the
module runs as ``python -m torchtasks.cli``. The ``bench`` tests are the benchmark smoke tests: they
check that the suite runs and writes its results, never the timings.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from torchtasks.cli import main

SUBCOMMANDS = ("demo", "list", "check", "bench")
HAS_MUJOCO = importlib.util.find_spec("mujoco") is not None and importlib.util.find_spec("gymnasium") is not None
needs_mujoco = pytest.mark.skipif(not HAS_MUJOCO, reason="needs the mujoco extra (mujoco, gymnasium)")


@pytest.fixture
def keep_threads():
    """Collectors change the number of torch threads of the main process; restore it."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


SPHINX_MARKUP = ("``", ":class:", ":func:", ":meth:", ":mod:", ":data:", ":attr:")


def _check_text(text: str, width: int = 100) -> None:
    """No traceback, no Sphinx markup, every line at most ``width`` columns."""
    assert "Traceback" not in text
    for markup in SPHINX_MARKUP:
        assert markup not in text, markup
    long = [line for line in text.splitlines() if len(line) > width]
    assert not long, long


def _listed(out: str) -> dict[str, dict[str, str]]:
    """``{module: {name: summary}}`` of ``torchtasks list``'s output (wrapped summaries joined)."""
    sections: dict[str, dict[str, str]] = {}
    entries: dict[str, str] = {}
    name = ""
    for line in out.splitlines():
        if re.match(r"^torchtasks[.\w]*: ", line):
            entries = sections.setdefault(line.split(":")[0], {})
        elif match := re.match(r"^  (\w+)(?:  +(.*))?$", line):
            name = match.group(1)
            entries[name] = match.group(2) or ""
        elif line.startswith("    ") and name:
            entries[name] = (entries[name] + " " + line.strip()).strip()
    return sections


def _markdown_rows(text: str) -> list[list[str]]:
    """The cells of every Markdown table row in ``text`` (header and separator rows included)."""
    return [
        [cell.strip() for cell in line.strip().strip("|").split("|")]
        for line in text.splitlines()
        if line.startswith("|")
    ]


# ------------------------------------------------------------------------------------------- help
@pytest.mark.quick
def test_help_lists_every_subcommand(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: torchtasks")
    for command in SUBCOMMANDS:
        assert command in out, command


@pytest.mark.parametrize("command", SUBCOMMANDS)
def test_subcommand_help(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: torchtasks {command}")


def test_subcommand_options_in_help(capsys: pytest.CaptureFixture[str]) -> None:
    expected = {
        "demo": ("--quick", "--output", "--seed", "--no-progress"),
        "check": ("ENV_ID", "--seeds", "--steps", "--backend", "--envs"),
        "bench": ("--output", "--tiny", "--sections"),
    }
    for command, options in expected.items():
        with pytest.raises(SystemExit):
            main([command, "--help"])
        out = capsys.readouterr().out
        for option in options:
            assert option in out, (command, option)


@pytest.mark.parametrize("command", ("", *SUBCOMMANDS))
def test_help_fits_a_screen(command: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """Every help fits 100 columns and, in an 80-column terminal, 30 lines; options show their defaults."""
    for columns in ("200", "80"):
        monkeypatch.setenv("COLUMNS", columns)
        with pytest.raises(SystemExit) as exit_info:
            main([command, "--help"] if command else ["--help"])
        assert exit_info.value.code == 0
        out = capsys.readouterr().out
        _check_text(out)
        assert len(out.splitlines()) <= 30, out
    if command == "check":
        for default in ("(default: 3)", "(default: 1000)", "(default: gymnasium)", "(default: runs/check)"):
            assert default in " ".join(out.split()), default


@pytest.mark.quick
def test_bare_command_prints_the_help(capsys: pytest.CaptureFixture[str]) -> None:
    """A bare ``torchtasks`` prints the help on stdout and returns 2 (nothing was run)."""
    assert main([]) == 2
    out = capsys.readouterr().out
    assert out.startswith("usage: torchtasks")
    for command in SUBCOMMANDS:
        assert f"    {command}  " in out, command


USER_MISTAKES = {
    "unknown command": (["frobnicate"], ("invalid choice: 'frobnicate'", "'demo', 'list', 'check', 'bench'")),
    "check without env": (["check"], ("required: ENV_ID",)),
    "lower-case env id": (
        ["check", "hopper-v5"],
        ("unknown env 'hopper-v5'; did you mean Hopper-v5?",),
    ),
    "not a MuJoCo preset": (
        ["check", "LunarLander-v3"],
        ("unknown env 'LunarLander-v3'; choose one of HalfCheetah-v5, Hopper-v5,", "or a Control Suite task"),
    ),
    "a Control Suite task misspelt": (["check", "cheetah_run"], ("did you mean cheetah-run?",)),
    "second env unknown": (["check", "Hopper-v5", "Hoper-v5"], ("unknown env 'Hoper-v5'", "did you mean Hopper-v5?")),
    "zero seeds": (["check", "Hopper-v5", "--seeds", "0"], ("--seeds: expected an integer >= 1, got '0'",)),
    "steps not a number": (["check", "Hopper-v5", "--steps", "many"], ("--steps: expected an integer >= 1",)),
    "negative envs": (["check", "Hopper-v5", "--backend", "batched", "--envs", "-1"], ("--envs: expected",)),
    "unknown backend": (["check", "Hopper-v5", "--backend", "jax"], ("'gymnasium', 'batched'",)),
    "--envs without batched": (["check", "Hopper-v5", "--envs", "2"], ("--envs applies to --backend batched",)),
    "unknown bench section": (["bench", "--sections", "speed"], ("'tasks', 'collector', 'memory'",)),
    "seed not a number": (["demo", "--seed", "x"], ("--seed: expected an integer from 0 to 2**63 - 1, got 'x'",)),
    "seed too large": (["demo", "--seed", str(2**64)], ("--seed: expected an integer from 0 to 2**63 - 1",)),
    "negative seed": (["demo", "--seed", "-1"], ("--seed: expected an integer from 0 to 2**63 - 1",)),
    "unknown option": (["list", "--all"], ("unrecognized arguments: --all",)),
    "misspelt option": (["demo", "--quik"], ("unrecognized arguments: --quik; did you mean '--quick'?",)),
    "misspelt option with a value": (["demo", "--quik=3"], ("arguments: --quik=3; did you mean '--quick'?",)),
    "misspelt option and its value": (["check", "Hopper-v5", "--stesp", "5"], ("5; did you mean '--steps'?",)),
    "two misspelt options": (["demo", "--quik", "--outptu", "x"], ("did you mean '--quick' and '--output'?",)),
    "misspelt option before the command": (["--quik", "demo"], ("did you mean '--quick'?",)),
    "ambiguous abbreviation": (["check", "Hopper-v5", "--s", "3"], ("--s could match --seeds, --steps",)),
    "misspelt choice of an option": (["check", "Hopper-v5", "--backend", "batchd"], ("did you mean 'batched'?",)),
    "misspelt command": (["chek"], ("invalid choice: 'chek'", "did you mean 'check'?")),
    "output inside a file": (["demo", "--output", "/dev/null/x"], ("--output: cannot create '/dev/null/x'",)),
    "output in /proc": (["demo", "--output", "/proc/nope"], ("--output: cannot create '/proc/nope': ",)),
    "output is a file": (["check", "Hopper-v5", "--output", __file__], ("exists and is not a folder",)),
}


@pytest.mark.parametrize("case", USER_MISTAKES)
def test_user_mistakes_are_one_line(case: str, capsys: pytest.CaptureFixture[str]) -> None:
    """A mistake in the arguments: one line on stderr naming the valid choices, exit status 2, no traceback,
    nothing run (no import of the mujoco extra is needed to reject an env id)."""
    argv, expected = USER_MISTAKES[case]
    try:
        code = main(argv)
    except SystemExit as exit_info:
        code = exit_info.code
    assert code == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.splitlines()
    assert len(lines) == 1, captured.err
    command = next((word for word in argv if word in SUBCOMMANDS), None)  # its parser reports the mistake
    assert lines[0].startswith(f"torchtasks {command}: " if command else "torchtasks: ")
    for text in expected:
        assert text in lines[0], (text, lines[0])
    assert ("did you mean" in lines[0]) == any("did you mean" in text for text in expected), lines[0]
    if "did you mean" in lines[0]:  # a suggestion, not the whole list: fits a terminal
        assert len(lines[0]) <= 100, lines[0]


def test_unknown_env_in_a_subprocess() -> None:
    """``torchtasks check hopper-v5`` as a user runs it: one line, status 2, no traceback."""
    result = subprocess.run(
        [sys.executable, "-m", "torchtasks.cli", "check", "hopper-v5"], capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 2
    assert result.stdout == ""
    assert result.stderr.splitlines() == ["torchtasks check: unknown env 'hopper-v5'; did you mean Hopper-v5?"]


def test_list_into_a_closed_pipe() -> None:
    """``torchtasks list | head``, with head gone before the list is written: no BrokenPipeError traceback."""
    process = subprocess.Popen(
        [sys.executable, "-m", "torchtasks.cli", "list"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    process.stdout.close()  # type: ignore[union-attr]  # the reader is gone before the first write
    stderr = process.stderr.read()  # type: ignore[union-attr]
    assert process.wait(timeout=300) == 141
    assert "Traceback" not in stderr and "BrokenPipe" not in stderr, stderr


def test_plain_text() -> None:
    from torchtasks.cli import plain_text

    assert plain_text("Base of :class:`ParallelTasks`:  ``nn.Module``\\ s") == "Base of ParallelTasks: nn.Modules"
    assert plain_text(":meth:`Task.transition <torchtasks.tasks.Task.transition>`") == "Task.transition"
    assert plain_text(":func:`~torchtasks.envs.locomotion.gymnasium_env` and `x`, **y**") == "gymnasium_env and x, y"


def test_module_entry_point() -> None:
    """``python -m torchtasks.cli --help`` works (the console script calls the same ``main``)."""
    result = subprocess.run(
        [sys.executable, "-m", "torchtasks.cli", "--help"], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("usage: torchtasks")


# ------------------------------------------------------------------------------------------- list
LIST_MODULES = (
    "torchtasks.rewards",
    "torchtasks.tasks",
    "torchtasks.predefined",
    "torchtasks.spaces",
    "torchtasks.domain",
    "torchtasks.transforms",
    "torchtasks.stats",
    "torchtasks.envs",
)


def test_list_shows_every_public_class_and_function(capsys: pytest.CaptureFixture[str]) -> None:
    """Grouped by module; every public class and function with a plain-text summary; no constants."""
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    _check_text(out)
    sections = _listed(out)
    assert list(sections) == list(LIST_MODULES)
    for module_name in LIST_MODULES:
        module = importlib.import_module(module_name)
        expected = {  # classes and functions; not constants (SIGMOIDS) or type aliases (LevelRule)
            name
            for name in module.__all__
            if name in vars(module) and (inspect.isclass(vars(module)[name]) or inspect.isroutine(vars(module)[name]))
        } | {name for name in module.__all__ if name not in vars(module)}  # lazy: the MuJoCo envs
        expected -= {"SUPPORTED_ENV_IDS", "MULTI_OBJECTIVE_ENV_IDS", "CONTROL_SUITE_TASKS"}
        assert set(sections[module_name]) == expected, module_name
    for module_name, name in (
        ("torchtasks.transforms", "TaskTransform"),
        ("torchtasks.transforms", "GoalCommand"),
        ("torchtasks.stats", "episode_statistics"),
        ("torchtasks.transforms", "Curriculum"),
        ("torchtasks.transforms", "DifficultyLevels"),
        ("torchtasks.tasks", "ConstrainedTask"),
        ("torchtasks.transforms", "BaseEnvState"),
        ("torchtasks.envs", "BatchedMujocoEnv"),
    ):
        assert sections[module_name][name], name
    summaries = {name: summary for entries in sections.values() for name, summary in entries.items()}
    empty = sorted(name for name, summary in summaries.items() if len(summary) < 10 or "no description" in summary)
    assert not empty, empty
    assert summaries["RewardFunction"].startswith("Base class of reward functions: nn.Modules mapping")
    assert summaries["TaskOutput"] == "The result of Task.transition for a batch of transitions."
    assert "HalfCheetah-v5, Hopper-v5" in out  # the Gymnasium ids of the MuJoCo presets
    assert "mo-hopper-v5, mo-hopper-2obj-v5" in " ".join(out.split())  # and MO-Gymnasium's, wrapped


def test_list_reads_each_source_file_once(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """The names ``list`` describes from the source (the lazily imported MuJoCo envs) follow the modules' imports:
    each module's source is read and parsed once, however many modules import from it (reading it again at every
    import took ~2,300 parses, 8 s a call)."""
    from torchtasks import cli

    for cached in (cli._parse, cli._defined_and_imported):
        cached.cache_clear()  # read the sources afresh in this test
    read: list[str] = []
    source_file = cli._source_file
    monkeypatch.setattr(cli, "_source_file", lambda name: read.append(name) or source_file(name))
    assert main(["list"]) == 0
    capsys.readouterr()
    assert read, "no source read"
    assert len(read) == len(set(read)), sorted({name for name in read if read.count(name) > 1})


# ------------------------------------------------------------------------------------------- demo
DEMO_FILES = {"torchtasks_demo.json", "torchtasks_demo.png"}


@pytest.mark.slow
def test_demo_quick(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], keep_threads
) -> None:
    """The quick demo's table and files; run from ``tmp_path`` with ``--output tmp_path/out``: nothing else appears."""
    monkeypatch.chdir(tmp_path)
    output = tmp_path / "out"
    assert main(["demo", "--quick", "--no-progress", "--output", str(output)]) == 0
    out = capsys.readouterr().out
    table = {row[0]: row[1] for row in _markdown_rows(out) if len(row) == 2}
    assert table["frames"] == "64,000"  # numbers as frames/s: with thousands separators
    assert int(table["successes"].replace(",", "")) > 0
    table_lines = [line for line in out.splitlines() if line.startswith("|")]
    assert len({len(line) for line in table_lines}) == 1, table_lines  # padded: the columns line up
    for name in ("frames/s", "action noise σ", "episodes ended", "failures", "truncations"):
        assert name in table, name
    for term in ("track", "effort", "final"):
        assert f"mean episode reward: {term}" in table, term
    assert sorted(path.name for path in tmp_path.iterdir()) == ["out"]
    assert {path.name for path in output.iterdir()} == DEMO_FILES
    for name in sorted(DEMO_FILES):
        assert f"wrote {output / name} " in out, name
    assert (output / "torchtasks_demo.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    metrics = json.loads((output / "torchtasks_demo.json").read_text())
    curves = metrics["curves"]
    assert metrics["summary"]["frames"] == 64000
    assert {len(values) for values in curves.values()} == {40}  # one value per batch of 1 600 frames
    rates = [rate for rate in curves["success_rate"] if rate is not None]
    returns = [value for value in curves["return"] if value is not None]
    # the action noise decays over the run: success rate and return rise (the curves are not flat)
    assert rates and rates[-1] == 1.0 and min(rates) < 0.8
    assert returns[-1] > returns[0] + 100


@pytest.mark.parametrize(
    ("argv", "folder"),
    [
        (["demo"], "runs/demo"),
        (["demo", "--quick"], "runs/demo/quick"),  # as the examples: a smoke run keeps the full run's results
        (["demo", "--qui"], "runs/demo/quick"),  # an abbreviation is the option
        (["demo", "--quick", "--output", "elsewhere"], "elsewhere"),
        (["demo", "--output", "a/b"], "a/b"),
        (["check", "Hopper-v5"], "runs/check"),
        (["bench", "--tiny"], "runs/bench"),
    ],
)
def test_output_folder_is_created_before_the_run(
    argv: list[str], folder: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every command with ``--output`` resolves it (the demo's ``--quick`` as the examples') and creates the folder
    before its run starts; the run (replaced here) gets that folder and nothing else is written."""
    from torchtasks import cli

    monkeypatch.chdir(tmp_path)
    runs: list[Path] = []
    for name in ("_cmd_demo", "_cmd_check", "_cmd_bench"):
        monkeypatch.setattr(cli, name, lambda args: runs.append(Path(args.output)) or 0)
    assert main(argv) == 0
    assert runs == [Path(folder)]
    assert (tmp_path / folder).is_dir() and not list((tmp_path / folder).iterdir())
    assert sorted(path.name for path in tmp_path.iterdir()) == [folder.split("/")[0]]


UNWRITABLE = {
    "in /proc (root may write anywhere else)": "/proc/nope",
    "below a missing folder of /proc": "/proc/nope/deeper",
    "inside a file": "/dev/null/x",
    "a file": __file__,
}


@pytest.mark.parametrize("command", [["demo"], ["demo", "--quick"], ["check", "Hopper-v5"], ["bench", "--tiny"]])
@pytest.mark.parametrize("case", UNWRITABLE)
def test_unwritable_output_is_refused_before_the_run(
    command: list[str], case: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """An ``--output`` that cannot be created (checked by creating it, not by ``os.access``, which says yes to root
    for ``/proc``): one line naming the folder and the system's reason, exit status 2, the run never starts."""
    from torchtasks import cli

    runs: list[str] = []
    for name in ("_cmd_demo", "_cmd_check", "_cmd_bench"):
        monkeypatch.setattr(cli, name, lambda args: runs.append(args.output) or 0)
    with pytest.raises(SystemExit) as exit_info:
        main([*command, "--output", UNWRITABLE[case]])
    assert exit_info.value.code == 2
    assert runs == []
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.splitlines()
    assert len(lines) == 1 and "Traceback" not in captured.err, captured.err
    assert lines[0].startswith(f"torchtasks {command[0]}: --output: "), lines[0]
    assert repr(UNWRITABLE[case]) in lines[0], lines[0]
    assert lines[0].split(repr(UNWRITABLE[case]), 1)[1].strip(": "), f"no reason given: {lines[0]}"


@pytest.mark.slow
def test_demo_writes_only_under_runs_demo(tmp_path: Path) -> None:
    """``torchtasks demo --quick`` run in ``tmp_path`` without ``--output`` writes ``runs/demo/quick/`` and nothing
    else; with stderr not a terminal (a log file), no progress bar is drawn into it."""
    result = subprocess.run(
        [sys.executable, "-m", "torchtasks.cli", "demo", "--quick"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    assert sorted(path.name for path in tmp_path.iterdir()) == ["runs"]
    assert sorted(path.name for path in (tmp_path / "runs").iterdir()) == ["demo"]
    assert sorted(path.name for path in (tmp_path / "runs" / "demo").iterdir()) == ["quick"]
    assert {path.name for path in (tmp_path / "runs" / "demo" / "quick").iterdir()} == DEMO_FILES
    assert f"wrote {Path('runs/demo/quick/torchtasks_demo.png')} (plot)" in result.stdout
    assert "\r" not in result.stderr and "swing-up demo" not in result.stderr, result.stderr[:200]


def test_demo_without_matplotlib(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, keep_threads) -> None:
    """Without matplotlib the demo writes its JSON curves and says how to get the plot."""
    from torchtasks.demo import run_demo

    monkeypatch.setitem(sys.modules, "matplotlib", None)
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    result = run_demo(total_frames=640, num_envs=8, frames_per_batch=320, output_dir=tmp_path / "demo", progress=False)
    assert result.plot_path is None
    assert result.plot_note is not None and "pip install" in result.plot_note and "[plot]'" in result.plot_note
    assert result.metrics_path == tmp_path / "demo" / "torchtasks_demo.json"
    assert [path.name for path in (tmp_path / "demo").iterdir()] == ["torchtasks_demo.json"]
    assert json.loads(result.metrics_path.read_text())["curves"]["frames"] == [320, 640]


# ----------------------------------------------------------------------- base install, extras
OPTIONAL_MODULES = ("gymnasium", "mujoco", "matplotlib", "ray")
CORE_IMPORT = (
    "import torchtasks, torchtasks.spaces, torchtasks.rewards, torchtasks.tasks, torchtasks.predefined, "
    "torchtasks.transforms, torchtasks.envs, torchtasks.cli"
)


REPO = Path(__file__).resolve().parents[2]


def _hint_outside_the_checkout(extra: str) -> str:
    """What a user outside the checkout must type (absolute paths; the bracketed target quoted for a shell)."""
    return f"pip install -c {REPO}/constraints.txt -e '{REPO}[{extra}]'"


def test_install_hints_say_what_works_where_the_package_came_from(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A checkout (make setup's editable install): the checkout's extra with its pins, relative inside it, absolute
    elsewhere; an installed wheel: the package's extra."""
    import torchtasks._optional as optional

    monkeypatch.chdir(REPO)
    assert optional.install_hint("mujoco") == "pip install -c constraints.txt -e '.[mujoco]'"
    monkeypatch.chdir(tmp_path)
    assert optional.install_hint("plot") == _hint_outside_the_checkout("plot")
    monkeypatch.setattr(optional, "checkout_root", lambda: None)
    assert optional.install_hint("ray") == "pip install 'torchtasks[ray]'"


def _python(code: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    result = subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    return result


def test_core_import_does_not_import_optional_modules(tmp_path: Path) -> None:
    """The core and ``torchtasks list`` import neither gymnasium nor matplotlib, even where they are installed.

    (mujoco and ray are imported by torchrl itself wherever they are installed, so they are blocked in
    ``test_core_and_list_without_the_extras`` and checked absent in ``.ci/check_base_install.sh``.)
    """
    code = f"""
import sys
{CORE_IMPORT}
from torchtasks.cli import main
main(["list"])
print("IMPORTED", sorted(name for name in ("gymnasium", "matplotlib") if name in sys.modules))
"""
    out = _python(code, tmp_path).stdout
    assert out.splitlines()[-1] == "IMPORTED []"
    assert "HalfCheetah-v5" in out  # the MuJoCo presets are listed by name all the same


def test_core_and_list_without_the_extras(tmp_path: Path) -> None:
    """With gymnasium, mujoco, matplotlib and ray absent (``sys.modules[name] = None``), the core imports,
    ``torchtasks list`` lists the MuJoCo presets and names the extra, and a preset's error names the extra."""
    code = f"""
import sys
for name in {OPTIONAL_MODULES!r}:
    sys.modules[name] = None
{CORE_IMPORT}
from torchtasks.cli import main
assert main(["list"]) == 0
try:
    torchtasks.envs.gymnasium_env
except ModuleNotFoundError as error:
    print("ERROR", error)
try:
    import torchtasks.envs.locomotion
except ModuleNotFoundError as error:
    print("ERROR", error)
print("CHECK", main(["check", "HalfCheetah-v5"]))
"""
    result = _python(code, tmp_path)
    out = result.stdout
    envs = _listed(out)["torchtasks.envs"]
    for name in ("PendulumEnv", "swing_up_task", "gymnasium_env", "locomotion_task", "BatchedMujocoEnv"):
        assert name in envs, name
    for name in ("gymnasium_env", "BatchedMujocoEnv", "ZeroBrokenStepReward"):
        assert envs[name].startswith("[needs the 'mujoco' extra] "), name
    assert envs["BatchedMujocoEnv"].endswith("any MuJoCo model in one process, one mujoco.batch call per step.")
    assert "[needs the 'mujoco' extra]" not in envs["PendulumEnv"]
    assert re.search(r"^  gymnasium_env .*\[needs the 'mujoco' extra\]", out, flags=re.MULTILINE)  # the CI's grep
    assert "HalfCheetah-v5" in out
    hint = _hint_outside_the_checkout("mujoco")
    assert f"[needs the 'mujoco' extra]: install it with\n  {hint}\n" in out  # a command to copy: not wrapped
    _check_text(out[: out.index("ERROR")].replace(str(REPO), "/home/user/torchtasks"))  # CI's checkout path varies
    errors = [line for line in out.splitlines() if line.startswith("ERROR")]
    assert len(errors) == 2
    for line in errors:
        assert f"needs the 'mujoco' extra: {hint}" in line, line
    assert out.splitlines()[-1] == "CHECK 2"
    assert f"torchtasks check needs the 'mujoco' extra: {hint}" in result.stderr


# ------------------------------------------------------------------------------------------ check
@pytest.mark.mujoco
@needs_mujoco
def test_check_halfcheetah(tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """A short check as on a terminal: a table of 100 columns, progress on stderr with its total, the details
    in a JSON file. (``--table full`` prints parity's full table: see test_batched_parity_check.py.)"""
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)  # the progress bar is drawn on a terminal only
    assert main(["check", "HalfCheetah-v5", "--seeds", "2", "--steps", "25", "--output", str(tmp_path)]) == 0
    captured = capsys.readouterr()
    (path,) = tmp_path.glob("check_gymnasium_*.json")
    _check_text(captured.out.replace(str(path), "PATH"))
    rows = _markdown_rows(captured.out)
    header, body = rows[0], rows[2:]
    assert len(body) == 1
    row = dict(zip(header, body[0], strict=True))
    assert row["env"] == "HalfCheetah-v5"
    assert (row["seeds"], row["steps"], row["flag mism."], row["obs mism."], row["result"]) == (
        "0-1",
        "50",
        "0",
        "0",
        "PASS",
    )
    assert float(row["reward diff"]) <= 1e-5
    assert "50/50" in captured.err and "Traceback" not in captured.err  # tqdm: steps done / total
    assert f"wrote {path} " in captured.out
    details = json.loads(path.read_text())
    assert details["rows"][0]["seeds"] == [0, 1] and details["rows"][0]["steps"] == 50
    assert set(details["rows"][0]["max_abs_term_diff"]) == {"forward", "ctrl"}
    assert details["table"][0].startswith("| env | seeds | steps |")  # parity's full table


@pytest.mark.mujoco
@needs_mujoco
def test_check_batched(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["check", "Swimmer-v5", "--backend", "batched", "--envs", "2", "--seeds", "1", "--steps", "12"]
    assert main([*argv, "--output", str(tmp_path), "--no-progress", "--table", "compact"]) == 0
    captured = capsys.readouterr()
    (path,) = tmp_path.glob("check_batched_*.json")
    _check_text(captured.out.replace(str(path), "PATH"))
    assert captured.err == ""
    rows = _markdown_rows(captured.out)
    row = dict(zip(rows[0], rows[2], strict=True))
    assert (row["env"], row["envs"], row["steps"], row["result"]) == ("Swimmer-v5", "2", "12", "PASS")
    assert json.loads(path.read_text())["rows"][0]["passed"] is True


@pytest.mark.mujoco
@needs_mujoco
def test_check_control_suite_against_dm_control(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A Control Suite task is compared with dm_control in the reference venv: a table that fits 100 columns, the
    details in a JSON file."""
    from torchtasks.envs.control_suite.reference import reference_python

    if reference_python() is None:
        pytest.skip("no dm_control reference venv (`make reference-venv` builds .venv-dmc)")
    argv = ["check", "reacher-hard", "cartpole-swingup", "--seeds", "2", "--steps", "15", "--envs", "2"]
    assert main([*argv, "--output", str(tmp_path), "--no-progress"]) == 0
    captured = capsys.readouterr()
    (path,) = tmp_path.glob("check_control_suite_*.json")
    _check_text(captured.out.replace(str(path), "PATH"))
    assert captured.err == ""
    rows = _markdown_rows(captured.out)
    body = [dict(zip(rows[0], row, strict=True)) for row in rows[2:]]
    assert [(row["task"], row["seeds"], row["envs"], row["result"]) for row in body] == [
        ("reacher-hard", "0-1", "2", "PASS"),
        ("cartpole-swingup", "0-1", "2", "PASS"),
    ]
    assert all(int(row["states"]) >= 2 * 2 * 15 for row in body)  # every step of every env of both seeds
    details = json.loads(path.read_text())["rows"]
    assert set(details[0]["observation"]) == {"position", "to_target", "velocity"}
    assert details[1]["worst"] <= 1e-8


@pytest.mark.mujoco
@needs_mujoco
def test_check_control_suite_refusals(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """No reference venv, a mix of kinds of ids, a misspelt task: one line on stderr, exit status 2, nothing run."""
    monkeypatch.setenv("TORCHTASKS_DM_CONTROL_PYTHON", "/nonexistent/python")
    assert main(["check", "walker-walk", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("torchtasks check: no dm_control reference: /nonexistent/python does not exist")
    assert "make reference-venv" in err and "Traceback" not in err
    assert main(["check", "walker-walk", "Hopper-v5"]) == 2
    assert "Control Suite tasks (walker-walk, ...) and Gymnasium ids in separate commands" in capsys.readouterr().err
    assert main(["check", "walker-wlak"]) == 2
    assert "unknown env 'walker-wlak'; did you mean walker-walk?" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------ bench
def _check_bench_outputs(folder: Path, section: str) -> dict:
    results = json.loads((folder / "benchmarks.json").read_text())
    markdown = (folder / "benchmarks.md").read_text()
    assert results["tiny"] is True
    assert results.get(section), f"no {section} results"
    assert markdown.startswith("# torchtasks benchmarks")
    assert "Tiny smoke run" in markdown
    return results


def test_bench_tiny_memory(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--tiny", "--sections", "memory", "--output", str(tmp_path)]) == 0
    results = _check_bench_outputs(tmp_path, "memory")
    assert set(results) == {"machine", "tiny", "memory"}
    cases = [row["case"] for row in results["memory"]]
    assert cases[:3] == ["T1", "T2", "T3"]
    sizes = {row["case"]: row["bytes_per_env"] for row in results["memory"]}
    assert all(isinstance(size, int) for size in sizes.values())
    assert all(sizes[case] > 0 for case in ("T1", "T2", "T3"))
    assert sizes.get("T4", 0) == 0  # the locomotion task reads Gymnasium's x_velocity: no memory
    markdown = (tmp_path / "benchmarks.md").read_text()
    assert "## Task memory" in markdown
    assert markdown in capsys.readouterr().out  # the same tables are printed


@pytest.mark.slow
def test_bench_tiny_tasks(tmp_path: Path) -> None:
    """One tiny run of the task-evaluation section (eager, compiled, hand-fused and numpy-loop paths)."""
    assert main(["bench", "--tiny", "--sections", "tasks", "--output", str(tmp_path)]) == 0
    results = _check_bench_outputs(tmp_path, "tasks")
    assert "memory" not in results and "collector" not in results
    rows = results["tasks"]
    assert {(row["case"], row["batch"]) for row in rows} >= {
        (case, batch) for case in ("T1", "T2", "T3") for batch in (1, 8)
    }
    for row in rows:
        for path in ("eager", "compiled", "fused", "numpy_loop"):
            assert row["us"][path] > 0, (row["case"], row["batch"], path)
    markdown = (tmp_path / "benchmarks.md").read_text()
    assert re.search(r"^\| T1 \| 1 \|", markdown, flags=re.MULTILINE)


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    """``torchtasks --version`` prints the package's version (pyproject.toml's) and exits with status 0."""
    import tomllib

    version = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out == f"torchtasks {version}\n"


def test_the_parser_and_argument_mistakes_do_not_import_torch(tmp_path: Path) -> None:
    """``--version``, ``--help`` and a refused argument answer at once: building the parser (the env ids of
    ``check`` are read from the source) imports neither torch nor the optional modules."""
    code = """
import sys
from torchtasks.cli import main
assert main(["check", "pendulum"]) == 2
for argv in (["--version"], ["check", "--help"], ["demo", "--output", "/dev/null/x"]):
    try:
        main(argv)
    except SystemExit:
        pass
loaded = sorted(name for name in ("torch", "tensordict", "torchrl", "mujoco", "gymnasium") if name in sys.modules)
print("LOADED", loaded)
"""
    result = _python(code, tmp_path)
    assert "LOADED []" in result.stdout, result.stdout
