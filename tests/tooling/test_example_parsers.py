"""The example scripts' command lines, without running them: every flag their docstrings and ``--help`` mention
exists, a misspelt option gets the option meant, an ``--output`` that cannot be created is refused first.

Each script runs in-process as ``__main__`` until it parses its arguments: the parser's ``parse_args`` is replaced
by one that hands the parser back (nothing is trained, nothing written).
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import logging
import re
import runpy
import sys
from pathlib import Path

import pytest

from example_runs import EXAMPLES
from torchtasks.cli import SuggestingParser

SCRIPTS = sorted(path.name for path in EXAMPLES.glob("[!_]*.py"))
WITH_OUTPUT = [name for name in SCRIPTS if "add_output_argument(" in (EXAMPLES / name).read_text(encoding="utf-8")]
FLAG = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")


class _Built(Exception):
    def __init__(self, parser: argparse.ArgumentParser) -> None:
        self.parser = parser


def _raise_built(parser: argparse.ArgumentParser, *args: object, **kwargs: object) -> argparse.Namespace:
    raise _Built(parser)


def build_parser(script: str, monkeypatch: pytest.MonkeyPatch) -> argparse.ArgumentParser:
    """The parser ``examples/<script>`` builds when run, captured at its ``parse_args`` call."""
    monkeypatch.syspath_prepend(str(EXAMPLES))
    monkeypatch.setattr(sys, "argv", [str(EXAMPLES / script)])
    monkeypatch.setattr(SuggestingParser, "parse_args", _raise_built)
    torchrl_logger = logging.getLogger("torchrl")
    monkeypatch.setattr(torchrl_logger, "level", torchrl_logger.level)  # the script quiets TorchRL's logger
    with pytest.raises(_Built) as built:
        runpy.run_path(str(EXAMPLES / script), run_name="__main__")
    monkeypatch.undo()
    return built.value.parser


def mentioned_flags(text: str) -> set[str]:
    """The ``--flags`` that ``text`` (reST) mentions as the script's own: a literal that starts with another
    command (``ray start --head``) names that command's flags, not the script's."""
    own = text
    for literal in re.findall(r"``(.*?)``", text, flags=re.DOTALL):
        first = literal.split()[0] if literal.split() else ""
        if not (first.startswith("-") or first == "python"):
            own = own.replace(f"``{literal}``", "")
    return set(FLAG.findall(own))


def test_the_scripts_are_found() -> None:
    assert len(SCRIPTS) >= 13 and len(WITH_OUTPUT) >= 9, (SCRIPTS, WITH_OUTPUT)


def test_mentioned_flags_reads_the_scripts_own() -> None:
    text = "Use ``--quick`` or ``python x.py [--seeds 0 1]``, with --output; start ``ray start --head`` first."
    assert mentioned_flags(text) == {"--quick", "--seeds", "--output"}


@pytest.mark.parametrize("script", SCRIPTS)
def test_every_flag_the_docs_mention_exists(script: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """A flag in the module docstring or in an option's help is one of the script's options (``--variant`` for
    ``--variants`` was not)."""
    parser = build_parser(script, monkeypatch)
    options = set(parser._option_string_actions)
    docstring = ast.get_docstring(ast.parse((EXAMPLES / script).read_text(encoding="utf-8"))) or ""
    missing = sorted(mentioned_flags(docstring) - options)
    assert not missing, f"{script}'s docstring mentions {missing}, not options of the script: {sorted(options)}"
    for action in parser._actions:
        missing = sorted(mentioned_flags(action.help or "") - options)
        assert not missing, f"{script}: the help of {action.option_strings} mentions {missing}"


@pytest.mark.parametrize("script", SCRIPTS)
def test_a_misspelt_option_gets_the_option_meant(
    script: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Every example parses with the ``torchtasks`` command's parser: ``--quik`` gets ``did you mean '--quick'?``
    (every example has ``--quick``), a choice-less unknown option gets no guess."""
    parser = build_parser(script, monkeypatch)
    assert isinstance(parser, SuggestingParser)
    for argv, expected in ((["--quik"], "--quik; did you mean '--quick'?\n"), (["--zzz"], "arguments: --zzz\n")):
        with pytest.raises(SystemExit) as exit_info:
            parser.parse_args(argv)
        assert exit_info.value.code == 2
        err = capsys.readouterr().err
        assert err.endswith(expected), err


@pytest.mark.parametrize("script", WITH_OUTPUT)
def test_an_output_that_cannot_be_created_is_refused_before_the_run(
    script: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--output /proc/nope`` (root may write anywhere else): one line with the system's reason, exit status 2,
    from the parsed arguments, before the run (``_cli.output_folder``, which every script with ``--output`` calls
    right after parsing)."""
    source = (EXAMPLES / script).read_text(encoding="utf-8")
    assert re.search(r"= output_folder\(parser, args, [^\n]*\)\n", source), f"{script} does not call output_folder"
    parser = build_parser(script, monkeypatch)
    monkeypatch.syspath_prepend(str(EXAMPLES))
    from _cli import output_folder

    args = parser.parse_args(["--quick", "--output", "/proc/nope"])
    with pytest.raises(SystemExit) as exit_info:
        output_folder(parser, args, Path("runs") / "x")
    assert exit_info.value.code == 2
    lines = capsys.readouterr().err.splitlines()
    assert lines[-1].startswith(f"{parser.prog}: error: --output: cannot create '/proc/nope': "), lines


# ------------------------------------------------------------------ train_multi_objective_ppo.py: the weight vectors
MO_SCRIPT = "train_multi_objective_ppo.py"


@pytest.fixture(scope="module")
def mo_example():
    """``examples/train_multi_objective_ppo.py`` as a module (it imports MuJoCo's presets)."""
    pytest.importorskip("mujoco")
    name = Path(MO_SCRIPT).stem
    sys.path.insert(0, str(EXAMPLES))
    try:
        spec = importlib.util.spec_from_file_location(name, EXAMPLES / MO_SCRIPT)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # dataclasses resolve the module of the config class by name
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(EXAMPLES))
    return module


def test_the_mo_default_weights_follow_the_env(mo_example, monkeypatch: pytest.MonkeyPatch) -> None:
    """Without ``--weights`` every MO env gets weight vectors of its own length: its record's scalarisation weights
    with the weights after the first scaled (the documented sweep for ``mo-halfcheetah-v5``)."""
    from torchtasks.envs.multi_objective import MULTI_OBJECTIVE_ENV_IDS, multi_objective_record

    parser = build_parser(MO_SCRIPT, monkeypatch)
    halfcheetah = mo_example.weight_sweep(parser, parser.parse_args([]), "mo-halfcheetah-v5")
    assert halfcheetah == ((1.0, 0.05), (1.0, 0.1), (1.0, 0.5), (1.0, 2.0))
    quick = mo_example.weight_sweep(parser, parser.parse_args(["--quick"]), "mo-halfcheetah-v5")
    assert quick == ((1.0, 0.1), (1.0, 2.0))
    for env_id in MULTI_OBJECTIVE_ENV_IDS:
        record = multi_objective_record(env_id)
        for argv in ([], ["--quick"]):
            vectors = mo_example.weight_sweep(parser, parser.parse_args(argv), env_id)
            assert vectors and all(len(vector) == len(record.objective_names) for vector in vectors), (env_id, vectors)
            assert record.weights in vectors, (env_id, vectors)  # the scalarisation that gives Gymnasium's reward
            assert len(set(vectors)) == len(vectors), (env_id, vectors)


def test_a_wrong_mo_weight_count_is_one_line(mo_example, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    """For every MO env, a weight vector of another length than its objectives, and an unknown env id, end the
    program with one line (exit status 2) naming the env, its objectives and what was given."""
    from torchtasks.envs.multi_objective import MULTI_OBJECTIVE_ENV_IDS, multi_objective_record

    parser = build_parser(MO_SCRIPT, monkeypatch)
    for env_id in MULTI_OBJECTIVE_ENV_IDS:
        names = multi_objective_record(env_id).objective_names
        for count in (len(names) - 1, len(names) + 1):
            given = ",".join(["1"] * count)
            args = parser.parse_args(["--weights", ",".join(["1"] * len(names)), given])  # the second is wrong
            with pytest.raises(SystemExit) as exit_info:
                mo_example.weight_sweep(parser, args, env_id)
            assert exit_info.value.code == 2
            lines = capsys.readouterr().err.splitlines()
            assert lines[-1] == (
                f"{parser.prog}: error: --weights: {env_id} has {len(names)} objectives ({', '.join(names)}), "
                f"so a weight vector needs {len(names)} weights; got {given}"
            ), lines
    with pytest.raises(SystemExit) as exit_info:
        mo_example.weight_sweep(parser, parser.parse_args([]), "mo-hoper-v5")
    assert exit_info.value.code == 2
    last = capsys.readouterr().err.splitlines()[-1]
    assert last.startswith(f"{parser.prog}: error: --env-id: unknown MO-Gymnasium env 'mo-hoper-v5'; did you mean"), (
        last
    )


def test_the_mo_example_refuses_a_wrong_count_before_any_work(
    monkeypatch: pytest.MonkeyPatch, capsys, tmp_path: Path
) -> None:
    """``--env-id mo-hopper-v5`` with a two-entry weight vector (Hopper has three objectives): the run ends at the
    argument check, with one error line and no traceback: no env built, no output folder made."""
    pytest.importorskip("mujoco")
    import torchtasks.envs.multi_objective as multi_objective

    def no_env(*args: object, **kwargs: object) -> None:
        raise AssertionError("an env was built before the weights were checked")

    monkeypatch.setattr(multi_objective, "multi_objective_env", no_env)
    output = tmp_path / "out"
    argv = [str(EXAMPLES / MO_SCRIPT), "--env-id", "mo-hopper-v5", "--weights", "1,0.1", "--output", str(output)]
    monkeypatch.syspath_prepend(str(EXAMPLES))
    monkeypatch.setattr(sys, "argv", argv)
    torchrl_logger = logging.getLogger("torchrl")
    monkeypatch.setattr(torchrl_logger, "level", torchrl_logger.level)  # the script quiets TorchRL's logger
    with pytest.raises(SystemExit) as exit_info:
        runpy.run_path(str(EXAMPLES / MO_SCRIPT), run_name="__main__")
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.splitlines()[-1].endswith("so a weight vector needs 3 weights; got 1,0.1")
    assert not output.exists()


# ------------------------------------------------------- the MuJoCo PPO examples: a bad flag refused before any work
#: script -> (the module and name of what builds its env, replaced by one that fails, (flags, error message) pairs)
REFUSED_FLAGS = {
    "own_robot_ppo.py": (
        "torchtasks.envs",
        "BatchedMujocoEnv",
        (
            (["--num-envs", "0"], "--num-envs must be at least 1, got 0"),
            (["--learning-rate", "-1"], "--learning-rate must be a positive number, got -1.0"),
        ),
    ),
    "velocity_tracking_ppo.py": (
        "torchtasks.envs",
        "velocity_tracking_env",
        (
            (["--num-envs", "0"], "--num-envs must be at least 1, got 0"),
            (["--curriculum-frames", "0"], "--curriculum-frames must be at least 1, got 0"),
        ),
    ),
    "control_suite_ppo.py": (
        "torchtasks.envs.control_suite",
        "control_suite_env",
        (
            (["--num-envs", "0"], "--num-envs must be at least 1, got 0"),
            (["--eval-steps", "0"], "--eval-steps must be at least 1, got 0"),
            (["--max-minutes", "nan"], "--max-minutes must be a positive number, got nan"),
            (["--task", "cheeta-run"], "--task: unknown Control Suite task 'cheeta-run'; did you mean 'cheetah-run'?"),
            (["--task", "walker"], "--task: unknown Control Suite task 'walker'"),
        ),
    ),
}


@pytest.mark.parametrize("script", sorted(REFUSED_FLAGS))
def test_the_mujoco_ppo_examples_refuse_a_bad_flag_before_any_work(
    script: str, monkeypatch: pytest.MonkeyPatch, capsys, tmp_path: Path
) -> None:
    """``--num-envs 0``, a non-positive learning rate, an unknown task, ...: one error line naming the flag, exit
    status 2, no traceback, no env built, no output folder made."""
    pytest.importorskip("mujoco")
    module_name, builder, cases = REFUSED_FLAGS[script]
    module = importlib.import_module(module_name)

    def no_env(*args: object, **kwargs: object) -> None:
        raise AssertionError("an env was built before the flags were checked")

    monkeypatch.setattr(module, builder, no_env)
    for flags, message in cases:
        output = tmp_path / "out"
        monkeypatch.syspath_prepend(str(EXAMPLES))
        monkeypatch.setattr(sys, "argv", [str(EXAMPLES / script), *flags, "--output", str(output)])
        torchrl_logger = logging.getLogger("torchrl")
        monkeypatch.setattr(torchrl_logger, "level", torchrl_logger.level)  # the script quiets TorchRL's logger
        with pytest.raises(SystemExit) as exit_info:
            runpy.run_path(str(EXAMPLES / script), run_name="__main__")
        assert exit_info.value.code == 2, flags
        err = capsys.readouterr().err
        assert "Traceback" not in err and err.splitlines()[-1].startswith(f"{script}: error: {message}"), err
        assert not output.exists()
