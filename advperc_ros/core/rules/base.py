"""What a rule is: a real-valued function of a rollout, per frame, with r < 0 a violation.

The paper defines an adversarial perception error against driving rules r(tau); a rule here is
evaluated at every frame of the executed drive, and its value over the rollout is the minimum, with
the first frame that violates it. Each rule is a class with this protocol, in its own module, named
in `registry.RULES`; its parameters are a frozen dataclass whose every field says where its default
comes from (`core.parameters.parameter`). This module is the interface only: it imports no rule, so any module may
import it (as the planners' base.py).
"""

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np

from advperc_ros.core.rules.inputs import RuleInputs

if TYPE_CHECKING:
    from _typeshed import DataclassInstance


@dataclass(frozen=True)
class NoParameters:
    """The parameters of a rule that has none (its definition fixes everything)."""


@dataclass(frozen=True)
class RuleValue:
    """A rule evaluated on one rollout: its value per frame, the rollout's value (their minimum) and
    the first frame that violates it, so a report can say both how badly and from when."""

    per_frame: np.ndarray  # (K,)
    value: float  # min over the frames; +inf for a rollout without frames
    first_violation: int | None  # the first frame whose value is < 0, None if none

    @property
    def violated(self) -> bool:
        return self.value < 0.0


def rule_value(per_frame: np.ndarray) -> RuleValue:
    """The rollout's value of a rule from its per-frame values: one definition for every rule."""
    per_frame = np.asarray(per_frame, dtype=float)
    below = np.flatnonzero(per_frame < 0.0)
    return RuleValue(per_frame, float(per_frame.min(initial=np.inf)), int(below[0]) if below.size else None)


class Rule(Protocol):
    """A driving rule: built from its parameters (`Parameters()` by default), a function of the
    executed drive per frame. A rule that judges the drive against the ground truth's rollout of the
    same scenario (`needs_reference`) is handed that rollout's inputs as `reference`."""

    name: ClassVar[str]  # how the registry and reports name it
    meaning: ClassVar[str]  # what r means, one line
    unit: ClassVar[str]  # r's unit
    needs_reference: ClassVar[bool]  # reads the ground truth's rollout
    Parameters: ClassVar["type[DataclassInstance]"]  # its frozen parameters dataclass, every field a `parameter`
    parameters: Any  # an instance of Parameters: what this rule was built with

    def __init__(self, parameters: Any = None) -> None: ...

    def per_frame(self, inputs: RuleInputs, reference: RuleInputs | None = None) -> np.ndarray:
        """(K,) r at every frame of `inputs`, r < 0 a violation."""


class ParameterisedRule:
    """What every rule class shares: it keeps its parameters, its `Parameters()` when given none."""

    Parameters: ClassVar["type[DataclassInstance]"] = NoParameters

    def __init__(self, parameters: Any = None) -> None:
        self.parameters = self.Parameters() if parameters is None else parameters


def evaluate(rule: Rule, inputs: RuleInputs, reference: RuleInputs | None = None) -> RuleValue:
    """`rule` on the rollout `inputs` (against the ground truth's rollout `reference` when it needs one)."""
    if rule.needs_reference and reference is None:
        raise ValueError(f"rule '{rule.name}' compares the rollout with the ground truth's: pass `reference`")
    return rule_value(rule.per_frame(inputs, reference))
