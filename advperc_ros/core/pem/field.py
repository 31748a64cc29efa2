"""What one field of a perception error model may hold: the check `schema` applies on loading, and
the terms declare for their own fields."""

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Field:
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
            bounded = math.isfinite(self.low) or math.isfinite(self.high)
            return f"a list of {self.count} numbers" + (f" in ({self.low:g}, {self.high:g})" if bounded else ", finite")
        what = "a whole number" if self.whole else "a number"
        return f"{what} in {'[' if self.closed else '('}{self.low}, {self.high})"
