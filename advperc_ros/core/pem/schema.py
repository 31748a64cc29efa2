"""What each field of a perception error model may hold, checked when a model is loaded, so a wrong
model fails on loading, not inside a rollout."""

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from advperc_ros.core.pem.densities import NUM_FEATURES
from advperc_ros.exceptions import PEMError

if TYPE_CHECKING:
    from advperc_ros.core.pem.model import PEM

MAX_LATENCY = 100  # frames a model's latency may be (a bound that keeps latency_source's loop short)


@dataclass(frozen=True)
class _Field:
    """What a model field holds: `count` numbers (None: a single one) within (low, high), `low` itself
    allowed if `closed`, a whole number if `whole`."""

    count: int | None
    low: float = -math.inf
    high: float = math.inf
    closed: bool = False
    whole: bool = False

    def admits(self, number: float | None) -> bool:
        if number is None or not (self.low < number < self.high or (self.closed and number == self.low)):
            return False
        return not self.whole or number == int(number)

    def describe(self) -> str:
        if self.count is not None:
            return f"a list of {self.count} numbers, finite"
        what = "a whole number" if self.whole else "a number"
        return f"{what} in {'[' if self.closed else '('}{self.low}, {self.high})"


FIELDS = {
    "detection": _Field(NUM_FEATURES),
    "position_loc": _Field(2),
    "radial_log_scale": _Field(NUM_FEATURES),
    "tangential_log_scale": _Field(NUM_FEATURES),
    "position_rho": _Field(None, -1.0, 1.0),
    "position_nu": _Field(None, 0.0),
    "yaw_log_scale": _Field(NUM_FEATURES),
    "yaw_nu": _Field(None, 0.0),
    "false_positive_rate": _Field(None, 0.0, 1000.0, closed=True),  # beyond, no detector (and no Poisson draw)
    "flip_near": _Field(None, 0.0, 1.0, closed=True),
    "flip_far": _Field(None, 0.0, 1.0, closed=True),
    "velocity_radial_scale": _Field(None, 0.0, closed=True),
    "velocity_tangential_scale": _Field(None, 0.0, closed=True),
    "velocity_nu": _Field(None, 0.0, closed=True),
    "length_log_loc": _Field(None),
    "length_log_std": _Field(None, 0.0, closed=True),
    "width_log_loc": _Field(None),
    "width_log_std": _Field(None, 0.0, closed=True),
    "latency": _Field(None, 0.0, MAX_LATENCY + 1.0, closed=True, whole=True),
    "position_ar": _Field(None, -1.0, 1.0),
}
REQUIRED = ("detection", "position_loc", "radial_log_scale", "tangential_log_scale", "position_rho", "position_nu",
             "yaw_log_scale", "yaw_nu", "source")  # the paper's parts; the others are optional terms
# terms whose fields are on or off together: (field that switches it, fields that must be above 0 with it)
TERMS = {"velocity": ("velocity_radial_scale", ("velocity_tangential_scale", "velocity_nu")),
          "size": ("length_log_std", ("width_log_std",))}


def checked(value, name: str, source: str):
    """A field's JSON value as the model holds it, or a PEMError saying what the field must be."""
    if name == "source":
        if not isinstance(value, str):
            raise PEMError(f"{source}: field 'source' must be a string")
        return value
    spec = FIELDS[name]
    items = [value] if spec.count is None else value if isinstance(value, list) and len(value) == spec.count else [None]
    numbers = [_number(item) for item in items]
    if not all(spec.admits(number) for number in numbers):
        shown = (f"a list of {len(value)}" if isinstance(value, list) else "an object" if isinstance(value, dict)
                 else f"{value!r:.60}")
        raise PEMError(f"{source}: field '{name}' must be {spec.describe()}, not {shown}")
    return numbers[0] if spec.count is None else tuple(numbers)


def check_terms(model: "PEM", source: str) -> None:
    """A term is on or off as a whole: its other scales (and degrees of freedom) are above 0 exactly
    when its switch is."""
    for term, (switch, others) in TERMS.items():
        on = getattr(model, switch) > 0.0
        for name in others:
            if (getattr(model, name) > 0.0) != on:
                raise PEMError(f"{source}: field '{name}' must be {'above 0' if on else '0'} when '{switch}' is "
                               f"{'above 0' if on else '0'} (the {term} term is on or off as a whole)")


def _number(value) -> float | None:
    """A JSON number as a float; None for anything else (booleans, strings, ints beyond a float)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        return float(value)
    except OverflowError:
        return None
