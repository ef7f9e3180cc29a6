"""Every public entry point of every task class rejects a wrong shape, dtype or batch in each tensor argument.

Property tests (hypothesis): a task of each class (``task_trees.class_cases`` and the predefined factories)
and one corrupted argument of one public call. The call must raise a ``ValueError`` or ``TypeError``
whose message names the corrupted argument; nothing is broadcast, truncated or cast silently.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from task_trees import class_cases, predefined_cases
from torchtasks.tasks import Task

CASES: dict[str, Callable[[], Task]] = {**class_cases(), **predefined_cases()}
BATCH = (3,)

# how an argument is corrupted: (description, function of the good tensor and the batch)
CORRUPTIONS: dict[str, Callable[[torch.Tensor], Any]] = {
    "one entry too many": lambda x: torch.cat([x, x[..., :1]], dim=-1),
    "one entry too few": lambda x: x[..., :-1] if x.shape[-1] > 1 else x[..., :0],
    "another batch": lambda x: torch.cat([x, x[:1]], dim=0),
    "a broadcastable batch": lambda x: x[:1],
    "an extra batch dim": lambda x: x.unsqueeze(0).expand(2, *x.shape),
    "integer dtype": lambda x: x.to(torch.int64),
    "half precision": lambda x: x.to(torch.float16),
    "not a tensor": lambda x: x.tolist(),
}
FLAG_CORRUPTIONS: dict[str, Callable[[torch.Tensor], Any]] = {
    "a trailing singleton": lambda x: x.unsqueeze(-1),
    "another batch": lambda x: torch.cat([x, x[:1]], dim=0),
    "a broadcastable batch": lambda x: x[:1],
    "float dtype": lambda x: x.to(torch.float32),
    "not a tensor": lambda x: x.tolist(),
}


BATCH_CHANGES = ("another batch", "a broadcastable batch", "an extra batch dim")


def _inputs(task: Task, batch: tuple[int, ...] = BATCH) -> dict[str, torch.Tensor]:
    generator = torch.Generator().manual_seed(0)
    state = torch.rand(*batch, task.state_size, generator=generator, dtype=torch.float64) * 0.2
    return {
        "state": state,
        "next_state": state + 0.01,
        "action": torch.rand(*batch, task.action_size, generator=generator, dtype=torch.float64),
        "terminated": torch.zeros(batch, dtype=torch.bool),
        "truncated": torch.zeros(batch, dtype=torch.bool),
        "done": torch.ones(batch, dtype=torch.bool),
    }


def _calls(task: Task, memory: Any) -> dict[str, tuple[Callable[..., Any], tuple[str, ...]]]:
    """Public call name -> (function of the named tensor arguments, the names of those arguments)."""
    return {
        "transition": (
            lambda state, action, next_state, terminated, truncated: task.transition(
                state, action, next_state, memory, terminated=terminated, truncated=truncated
            ),
            ("state", "action", "next_state", "terminated", "truncated"),
        ),
        "step_reward": (lambda state, action: task.step_reward(state, action, memory), ("state", "action")),
        "step_reward_terms": (lambda state, action: task.step_reward_terms(state, action, memory), ("state", "action")),
        "has_succeeded": (lambda state: task.has_succeeded(state, memory), ("state",)),
        "has_failed": (lambda state: task.has_failed(state, memory), ("state",)),
        "is_done": (lambda state: task.is_done(state, memory), ("state",)),
        "final_reward": (lambda state, done: task.final_reward(state, memory, 0, done), ("state", "done")),
        "reset": (lambda state: task.reset(state), ("state",)),
    }


def _argument_name(call: str, argument: str) -> str:
    return "init_state" if call == "reset" else argument


CALL_ARGUMENTS = {
    "transition": ("state", "action", "next_state", "terminated", "truncated"),
    "step_reward": ("state", "action"),
    "step_reward_terms": ("state", "action"),
    "has_succeeded": ("state",),
    "has_failed": ("state",),
    "is_done": ("state",),
    "final_reward": ("state", "done"),
    "reset": ("state",),
}
COMBINATIONS = [
    (call, argument, corruption)
    for call, arguments in CALL_ARGUMENTS.items()
    for argument in arguments
    for corruption in sorted(FLAG_CORRUPTIONS if argument in ("terminated", "truncated", "done") else CORRUPTIONS)
    if not (call == "reset" and corruption in BATCH_CHANGES)  # reset sets the batch: any batch is valid
]


@pytest.mark.parametrize(("call", "argument", "corruption"), COMBINATIONS)
@settings(max_examples=12, deadline=None, derandomize=True)
@given(case=st.sampled_from(sorted(CASES)), batch=st.sampled_from([(3,), (2, 3)]))
def test_every_entry_point_rejects_a_corrupted_argument_and_names_it(
    call: str, argument: str, corruption: str, case: str, batch: tuple[int, ...]
):
    task = CASES[case]()
    inputs = _inputs(task, batch)
    memory = task.reset(inputs["state"])
    function, arguments = _calls(task, memory)[call]
    corrupt = {**CORRUPTIONS, **FLAG_CORRUPTIONS}[corruption]
    if corruption == "one entry too few" and argument == "action" and task.action_size == 0:
        return
    kwargs = {key: inputs[key] for key in arguments}
    kwargs[argument] = corrupt(inputs[argument])
    with pytest.raises((ValueError, TypeError)) as raised:
        function(**kwargs)
    assert _argument_name(call, argument) in str(raised.value), (case, str(raised.value))


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_good_arguments_pass_every_entry_point(case: str):
    """The control: the uncorrupted arguments are accepted by every call (so the test above tests the checks)."""
    task = CASES[case]()
    inputs = _inputs(task)
    memory = task.reset(inputs["state"])
    for function, arguments in _calls(task, memory).values():
        function(**{key: inputs[key] for key in arguments})
