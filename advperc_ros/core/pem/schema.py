"""What each field of a perception error model may hold, checked when a model is loaded, so a wrong
model fails on loading, not inside a rollout."""

from typing import TYPE_CHECKING

from advperc_ros.core.pem.densities import NUM_FEATURES
from advperc_ros.core.pem.field import Field
from advperc_ros.core.pem.terms import TERMS
from advperc_ros.exceptions import PEMError

if TYPE_CHECKING:
    from advperc_ros.core.pem.model import PEM

# a log-scale coefficient's bound: e^30 is a scale no detector's error has, and beyond it a density underflows to 0
# (a PEM LL of -inf, which is no number a report or `advperc score` can print)
LOG_SCALE_BOUND = 30.0
# the paper's parts' fields and the model's own persistence; each term beyond the paper declares its own (`terms`)
PAPER_FIELDS = {
    "detection": Field(NUM_FEATURES),
    "position_loc": Field(2),
    "radial_log_scale": Field(NUM_FEATURES, -LOG_SCALE_BOUND, LOG_SCALE_BOUND),
    "tangential_log_scale": Field(NUM_FEATURES, -LOG_SCALE_BOUND, LOG_SCALE_BOUND),
    "position_rho": Field(None, -1.0, 1.0),
    "position_nu": Field(None, 0.0),
    "yaw_log_scale": Field(NUM_FEATURES, -LOG_SCALE_BOUND, LOG_SCALE_BOUND),
    "yaw_nu": Field(None, 0.0),
    "position_ar": Field(None, -1.0, 1.0),
}
FIELDS = {**PAPER_FIELDS, **{name: field for term in TERMS for name, field in term.fields.items()}}
REQUIRED = ("detection", "position_loc", "radial_log_scale", "tangential_log_scale", "position_rho", "position_nu",
            "yaw_log_scale", "yaw_nu", "source")  # the paper's parts; the others are optional terms


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
    when its switch, the first of `Term.together`, is."""
    for term in TERMS:
        switch, others = term.together[0] if term.together else "", term.together[1:]
        on = bool(switch) and getattr(model, switch) > 0.0
        for name in others:
            if (getattr(model, name) > 0.0) != on:
                raise PEMError(f"{source}: field '{name}' must be {'above 0' if on else '0'} when '{switch}' is "
                               f"{'above 0' if on else '0'} (the {term.kind} term is on or off as a whole)")


def _number(value) -> float | None:
    """A JSON number as a float; None for anything else (booleans, strings, ints beyond a float)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        return float(value)
    except OverflowError:
        return None
