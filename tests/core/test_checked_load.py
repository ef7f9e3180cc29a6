"""``CheckedLoad``: a refused load changes nothing, in the refusing module and in the modules with run state loaded
before it in the same ``load_state_dict`` call (as TorchRL's ``env.load_state_dict`` loads a ``Compose``)."""

from __future__ import annotations

from typing import Any

import pytest
import torch
from torch import nn

from torchtasks._checked_load import CheckedLoad


class Counter(CheckedLoad):
    """A module with a count that refuses a checkpoint of another ``kind`` (before writing) and a count < 0 (after)."""

    def __init__(self, kind: str, count: float = 0.0) -> None:
        super().__init__()
        self.kind = kind
        self.register_buffer("count", torch.tensor(count))

    def get_extra_state(self) -> dict[str, str]:
        return {"kind": self.kind}

    def set_extra_state(self, state: Any) -> None:
        pass

    def _check_saved(self, state_dict: Any, prefix: str) -> None:
        saved = state_dict.get(prefix + "_extra_state", {}).get("kind")
        if saved != self.kind:
            raise ValueError(f"Counter: a checkpoint of kind {saved!r}, this one is {self.kind!r}")

    def _check_loaded(self) -> None:
        if bool(self.count < 0):
            raise ValueError("Counter: the count must be >= 0")


def _compose(*counters: Counter) -> nn.Module:
    """Modules loaded one after the other, as the transforms of a TorchRL ``Compose``."""
    return nn.ModuleList(counters)


def _counts(module: nn.Module) -> list[float]:
    return [float(counter.count) for counter in module]


@pytest.mark.parametrize("refusal", ["before writing", "after loading"])
@pytest.mark.parametrize("refusing", [1, 2])
def test_a_refusal_puts_back_the_modules_loaded_before_it_in_the_same_call(refusal: str, refusing: int) -> None:
    saved = _compose(Counter("a", 1.0), Counter("b", 2.0), Counter("c", 3.0))
    checkpoint = saved.state_dict()
    if refusal == "before writing":
        kinds = ["a", "b", "c"]
        kinds[refusing] = "other"
    else:
        kinds = ["a", "b", "c"]
        checkpoint[f"{refusing}.count"] = torch.tensor(-1.0)
    target = _compose(*(Counter(kind, 10.0 * (i + 1)) for i, kind in enumerate(kinds)))
    with pytest.raises(ValueError, match="Counter: "):
        target.load_state_dict(checkpoint)
    assert _counts(target) == [10.0, 20.0, 30.0]  # the modules before the refusing one too
    # a next load is a load of its own
    target.load_state_dict(_compose(*(Counter(kind, i + 1.0) for i, kind in enumerate(kinds))).state_dict())
    assert _counts(target) == [1.0, 2.0, 3.0]


def test_a_refusal_leaves_the_modules_of_an_earlier_call_loaded() -> None:
    first, second = _compose(Counter("a"), Counter("b")), _compose(Counter("a"), Counter("b"))
    first.load_state_dict(_compose(Counter("a", 1.0), Counter("b", 2.0)).state_dict())
    with pytest.raises(ValueError, match="the count must be >= 0"):
        second.load_state_dict(_compose(Counter("a", 5.0), Counter("b", -1.0)).state_dict())
    assert _counts(first) == [1.0, 2.0] and _counts(second) == [0.0, 0.0]


def test_a_module_loaded_alone_and_nested_modules_are_checked_and_put_back_alike() -> None:
    alone = Counter("a", 4.0)
    with pytest.raises(ValueError, match="the count must be >= 0"):
        alone.load_state_dict({"count": torch.tensor(-2.0), "_extra_state": {"kind": "a"}})
    assert float(alone.count) == 4.0
    # a module with run state inside another (a DomainRandomization's parameters): the inner ones count too
    outer = nn.ModuleList([_compose(Counter("a", 1.0), Counter("b", 2.0)), Counter("c", 3.0)])
    checkpoint = nn.ModuleList([_compose(Counter("a", 7.0), Counter("b", 8.0)), Counter("other", 9.0)]).state_dict()
    with pytest.raises(ValueError, match="a checkpoint of kind 'other'"):
        outer.load_state_dict(checkpoint)
    assert _counts(outer[0]) == [1.0, 2.0] and float(outer[1].count) == 3.0
