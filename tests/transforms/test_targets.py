"""The one target resolver (``torchtasks.transforms.targets``) that a Curriculum and DifficultyLevels share.

Both writers resolve their names, check their values and write them through it: a misspelt name, a GoalCommand
placed before the writer and a range outside the goal space get one message whichever writer meets them, the
write keeps or replaces the buffer as the grad mode asks, and the entry names are read from one module.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest
import torch
from torch import nn
from torchrl.envs import Compose, StepCounter, TransformedEnv

from repo_paths import ROOT
from torchtasks.spaces import Box
from torchtasks.transforms import Curriculum, DifficultyLevels, GoalCommand, TaskTransform, constant
from torchtasks.transforms.targets import TASK, Target
from walk_env import WalkEnv, walk_task

TRANSFORMS = ROOT / "src" / "torchtasks" / "transforms"
# the float buffers of walk_task(), as task.named_buffers() names them (a DesiredStateTask around a quadratic reward)
TASK_BUFFERS = ["reward.Q", "reward.R", "state_des", "state_high", "state_low"]


def _writer(kind: str, values: dict) -> Curriculum | DifficultyLevels:
    """A Curriculum of constant schedules or two-level DifficultyLevels, setting ``values`` (one value per name)."""
    if kind == "Curriculum":
        return Curriculum({name: constant(value) for name, value in values.items()})
    return DifficultyLevels(2, {name: [value, value] for name, value in values.items()})


def _env(writer: nn.Module, *, command_first: bool = False) -> TransformedEnv:
    """A WalkEnv of 4 envs tracking a goal drawn in [-1, 1] by a GoalCommand after (or before) the writer."""
    command = GoalCommand(Box([-1.0], [1.0]), seed=0)
    order = [command, writer] if command_first else [writer, command]
    return TransformedEnv(WalkEnv([4]), Compose(StepCounter(5), TaskTransform(walk_task(), goal_key="goal"), *order))


@pytest.mark.parametrize(
    ("kind", "bad", "good"),
    [
        ("Curriculum", "rewrd.Q", "reward.Q"),
        ("Curriculum", "command.hihg", "command.high"),
        ("DifficultyLevels", "comand.low", "command.low"),
        ("DifficultyLevels", "stat_des", "state_des"),
        ("DifficultyLevels", "env.step_siz", "env.step_size"),
    ],
)
def test_an_unknown_name_gets_one_message_listing_every_name_the_writer_can_set(kind, bad, good):
    value = [0.5] if kind == "DifficultyLevels" else 0.5
    with pytest.raises(ValueError, match="unknown target") as error:
        _env(_writer(kind, {bad: value})).reset()
    message = str(error.value)
    assert message.startswith(f"{kind}: unknown target {bad!r}; did you mean {good!r}? It is not in the ")
    settable = (
        TASK_BUFFERS + (["env.step_size"] if kind == "DifficultyLevels" else []) + ["command.high", "command.low"]
    )
    assert f"the names {kind} can set are {settable} (float buffers are named as named_buffers() names them" in message


@pytest.mark.parametrize("kind", ["Curriculum", "DifficultyLevels"])
def test_a_goal_command_before_the_writer_gets_one_message(kind):
    value = [-0.5] if kind == "DifficultyLevels" else -0.5
    with pytest.raises(ValueError) as error:
        _env(_writer(kind, {"command.low": value}), command_first=True).reset()
    assert str(error.value) == (
        f"{kind} sets 'command.low' of the GoalCommand writing 'goal', which comes before it: put {kind} before it "
        "(before that GoalCommand in the Compose, after the TaskTransform), so that the goal drawn in a step uses "
        "that step's range"
    )


@pytest.mark.parametrize("kind", ["Curriculum", "DifficultyLevels"])
@pytest.mark.parametrize("bound", ["low", "high"])
def test_a_range_outside_the_goal_space_gets_one_message(kind, bound):
    outside = -1.5 if bound == "low" else 1.5
    value = [outside] if kind == "DifficultyLevels" else outside
    with pytest.raises(ValueError) as error:
        _env(_writer(kind, {f"command.{bound}": value})).reset()
    pattern = (
        rf"{kind}: .* leaves the GoalCommand's space: .*\[{outside}\].* leaves the goal space of the GoalCommand "
        r"writing 'goal' \(its goal spec, low=\[-1\.0\], high=\[1\.0\]\); build the GoalCommand with a Box that "
        "holds the widest range"
    )
    assert re.fullmatch(pattern, str(error.value)), str(error.value)


@pytest.mark.parametrize("replace", [False, True], ids=["copy", "replace"])
@pytest.mark.parametrize(
    ("value", "expected"),
    [
        (torch.tensor([4.0, 5.0, 6.0], dtype=torch.float64), [4.0, 5.0, 6.0]),
        (torch.tensor(7.0, dtype=torch.float64), [7.0, 7.0, 7.0]),  # a scalar value fills the buffer
        (8.0, [8.0, 8.0, 8.0]),  # a host float (a frame-driven schedule's value)
    ],
    ids=["tensor", "scalar-tensor", "float"],
)
def test_a_write_copies_into_the_buffer_or_puts_a_new_one_in_its_place(value, expected, replace):
    module = nn.Module()
    module.register_buffer("weight", torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    before = module.weight
    version = before._version
    target = Target("weight", module, "weight", TASK, torch.Size([3]), per_env=False)
    written = target.write(value, replace=replace)
    assert written is module.weight and module.weight.dtype == torch.float64 and module.weight.tolist() == expected
    if replace:  # the old tensor, which an earlier step's graph may hold, keeps its values
        assert written is not before and before.tolist() == [1.0, 2.0, 3.0] and before._version == version
        if isinstance(value, torch.Tensor):  # a copy: the caller's tensor may go into the data unchanged
            assert written.data_ptr() != value.data_ptr()
    else:
        assert written is before and before._version > version


@pytest.mark.parametrize("other", ["Curriculum", "DifficultyLevels"])
def test_levels_refuse_a_buffer_another_writer_of_the_env_sets(other):
    """Whichever of the two writers resolves first refuses the buffer the other one also sets."""
    if other == "Curriculum":
        first = Curriculum({"command.high": constant(0.5)})
        levels = DifficultyLevels(2, {"command.high": [[0.5], [1.0]]})
    else:  # levels under another key setting the same per-env buffer of the base env
        first = DifficultyLevels(2, {"env.step_size": [0.4, 0.2]}, curriculum_key="other")
        levels = DifficultyLevels(2, {"env.step_size": [0.3, 0.1]})
    command = GoalCommand(Box([-1.0], [1.0]), seed=0)
    task = TaskTransform(walk_task(), goal_key="goal")
    env = TransformedEnv(WalkEnv([4]), Compose(StepCounter(5), task, first, levels, command))
    one_owner = r"(DifficultyLevels|Curriculum) sets .*, which a (DifficultyLevels|Curriculum) of the env also sets"
    with pytest.raises(ValueError, match=one_owner + " as .*: a buffer has one owner") as refused:
        env.reset()
    assert other in str(refused.value) and "DifficultyLevels" in str(refused.value)


def _imports(path: Path) -> list[ast.ImportFrom]:
    return [node for node in ast.walk(ast.parse(path.read_text())) if isinstance(node, ast.ImportFrom)]


def test_no_transform_module_imports_another_ones_private_names_and_levels_not_curriculum():
    for path in sorted(TRANSFORMS.glob("*.py")):
        for node in _imports(path):
            if (node.module or "").startswith("torchtasks.transforms."):
                private = [alias.name for alias in node.names if alias.name.startswith("_")]
                assert not private, f"{path.name} imports {private} from {node.module}"
    assert "torchtasks.transforms.curriculum" not in {node.module for node in _imports(TRANSFORMS / "levels.py")}
    source = (TRANSFORMS / "levels.py").read_text()
    assert "_get_slots" not in source and "._resolve" not in source


@pytest.mark.parametrize(
    "path", [ROOT / "src" / "torchtasks" / "stats.py", TRANSFORMS / "task.py", TRANSFORMS / "targets.py"]
)
def test_the_readers_of_the_run_entries_do_not_spell_their_names(path):
    """The entry names and target prefixes are spelt in transforms/names.py; its readers import them."""
    spelt = {"frames", "level", "curriculum", "command", "env", "command.", "env."}
    literals = [
        (node.lineno, node.value)
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, ast.Constant) and node.value in spelt
    ]
    assert not literals, f"{path.name} spells {literals}"
