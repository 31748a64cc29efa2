"""A model's parameters with their sources: what a driving rule and the reactive traffic declare.

Every parameter of a rule (core.rules) or of the traffic model (core.traffic) is a field of a frozen
dataclass made with `parameter`: its default, where that default comes from, and the values it may
take. The params schema, the docs and the tests read all three through `parameter_info`, so no
default is a bare number and a value that makes no sense is refused before any rollout.
"""

from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any, cast

if TYPE_CHECKING:
    from _typeshed import DataclassInstance


@dataclass(frozen=True)
class Bounds:
    """The values a rule parameter may take: what the params file's `rule.<rule>.<parameter>` is
    checked against, so a threshold that makes no sense (a negative time, braking bound above 0) is
    refused with one line before any rollout."""

    low: float | None = None  # smallest value allowed
    high: float | None = None  # largest value allowed
    positive: bool = False  # strictly above 0


def parameter(default: float, source: str, bounds: Bounds) -> Any:
    """A rule parameter's field: its default, where that default comes from and the values it may take
    (`parameter_info` lists all three, for the params schema, the docs and the tests)."""
    return field(default=default, metadata={"source": source, "bounds": bounds})


@dataclass(frozen=True)
class ParameterInfo:
    """One parameter of a rule: its default, the default's source and its bounds, so no default is a bare number."""

    name: str
    default: float
    source: str
    bounds: Bounds


def parameter_info(parameters_type: "type[DataclassInstance]") -> tuple[ParameterInfo, ...]:
    """The parameters of a rule's parameters dataclass, with their defaults, sources and bounds."""
    # every field is a `parameter`, so every one has its default
    return tuple(ParameterInfo(f.name, cast(float, f.default), f.metadata["source"], f.metadata["bounds"])
                 for f in fields(parameters_type))
