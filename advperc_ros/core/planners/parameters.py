"""The bundled planners' parameters: one rule for what a params file may give each field of a
planner's frozen config dataclass, one for ranges. A bad value raises TypeError (wrong kind, unknown
name) or ValueError (out of range) naming the parameter, at construction; `load_planner` turns
either into a PluginError naming the planner as well."""

import math
from dataclasses import fields
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

Config = TypeVar("Config", bound="DataclassInstance")


def config_from_params(config_type: type[Config], params: dict[str, Any]) -> Config:
    """`config_type(**params)` with numbers for number fields (a YAML 10 is a fine 10.0), whole
    numbers for int fields, true/false for bool fields and text for str fields (a variant's name); its
    __post_init__ checks the ranges."""
    # types, not strings: no config postpones its annotations
    kinds: dict[str, Any] = {field.name: field.type for field in fields(config_type)}
    values = {}
    for name, value in params.items():
        if name not in kinds:
            raise TypeError(f"unexpected parameter '{name}'")
        kind = kinds[name]
        if kind is bool:
            if not isinstance(value, bool):
                raise TypeError(f"parameter '{name}' must be true or false, got {value!r}")
        elif kind is str:
            if not isinstance(value, str):
                raise TypeError(f"parameter '{name}' must be text, got {value!r}")
        elif isinstance(value, bool) or not isinstance(value, (int, float)):
            raise TypeError(f"parameter '{name}' must be a number, got {value!r}")
        elif kind is int and not (math.isfinite(value) and float(value).is_integer()):
            raise TypeError(f"parameter '{name}' must be an integer, got {value!r}")
        values[name] = kind(value)
    return config_type(**values)


def check_ranges(config: object, positive: tuple[str, ...] = (), non_negative: tuple[str, ...] = (),
                 at_most: dict[str, float] | None = None) -> None:
    """Refuse the first of these fields that is not a finite number > 0 (positive) or >= 0, or is above
    its `at_most` bound (a horizon of 1e9 s asked for 74 GiB of plan and was blamed on the planner)."""
    for name, bound in (at_most or {}).items():
        value = getattr(config, name)
        if value > bound:
            raise ValueError(f"parameter '{name}' must be at most {bound:g}, got {value!r}")
    for name in positive:
        value = getattr(config, name)
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"parameter '{name}' must be a finite number > 0, got {value!r}")
    for name in non_negative:
        value = getattr(config, name)
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"parameter '{name}' must be a finite number >= 0, got {value!r}")
