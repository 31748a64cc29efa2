"""The `advperc` command's argument types: each a parse of one flag's text that argparse reports, as every other
bad input, in one line with exit code 2 (`OneLineParser`)."""

import argparse
from typing import NoReturn

from advperc_ros.core.perception_errors import parse_error_kinds
from advperc_ros.exits import EXIT_INPUT


class OneLineParser(argparse.ArgumentParser):
    """argparse's refusals as every other bad input: one line, exit code 2 (`advperc -h` for usage)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_INPUT, f"advperc: error: {self.prog}: {message}\n")


def count(text: str) -> int:
    """A number of samples: a whole number, at least 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def pathname(text: str) -> str:
    """A path argument: an empty one (`--output ''`) names nothing, and was taken for the default."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path names nothing; give one or leave the flag out")
    return text


def error_kinds(text: str) -> tuple[str, ...]:
    """Error kinds as `errors.kinds` names them (paper, all, or a comma-separated list)."""
    try:
        return parse_error_kinds(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def strengths(text: str) -> tuple[float, ...]:
    """Perturbation strengths: comma-separated probabilities in [0, 1]."""
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if not all(0.0 <= value <= 1.0 for value in values):
        raise argparse.ArgumentTypeError(f"each strength is a probability in [0, 1], got {text!r}")
    return values


def radii(text: str) -> tuple[float, ...]:
    """Distance bins' outer radii: comma-separated numbers of metres (checked further with the request)."""
    try:
        return tuple(float(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated radii in m, as 20,40,60, got {text!r}") from None
