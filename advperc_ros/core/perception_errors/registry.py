"""The error kinds, in order: the paper's three, then the kinds beyond it.

Adding a kind: a module in `kinds/` defining its `ErrorKind` (`KIND`) and one line here; the tensor
holds its arrays by their names (`PerceptionErrors.extended`). The order is the tensor's array
order, so files, messages and digests keep it: add a kind at the end. Everything that loops over
kinds reads `KINDS` when it runs, so a test may register a kind of its own.
"""

from advperc_ros.core.perception_errors.kind import ArraySpec, Bound, ErrorKind
from advperc_ros.core.perception_errors.kinds import drop, flip, ghost, latency, position, size, velocity, yaw

KINDS: tuple[ErrorKind, ...] = (
    position.KIND,
    yaw.KIND,
    drop.KIND,
    velocity.KIND,
    size.KIND,
    flip.KIND,
    latency.KIND,
    ghost.KIND,
)

PAPER_KINDS = tuple(kind.name for kind in KINDS if kind.paper)  # the paper's error space: its arrays are always there
PAPER_ARRAYS = tuple(name for kind in KINDS if kind.paper for name in kind.array_names)
ERROR_KINDS = tuple(kind.name for kind in KINDS)
# the kinds beyond the paper and the optional arrays each adds to the tensor
EXTENDED_KINDS: dict[str, tuple[str, ...]] = {kind.name: kind.array_names for kind in KINDS if not kind.paper}


def kind_named(name: str) -> ErrorKind:
    """The registered kind `name`; a ValueError naming the known ones otherwise."""
    for kind in KINDS:
        if kind.name == name:
            return kind
    raise ValueError(f"unknown error kind {name!r} (known: {', '.join(kind.name for kind in KINDS)})")


def array_specs() -> dict[str, ArraySpec]:
    """Every registered array by name, in field order."""
    return {spec.name: spec for kind in KINDS for spec in kind.arrays}


def bounds() -> dict[str, Bound]:
    """Every registered kind's limits on the error space by name, in kind order (the `errors.*` params)."""
    return {bound.name: bound for kind in KINDS for bound in kind.bounds}


def parse_error_kinds(text: str) -> tuple[str, ...]:
    """The kinds `errors.kinds` names: `paper`, `all`, or a comma-separated list of kind names, in
    `ERROR_KINDS` order; a ValueError naming what is wrong otherwise. The paper's kinds are always on:
    the search finds its failure mode with drops (Algorithm 1) and moves by offsets, so a list names
    the extended kinds added to them (naming a paper kind too is allowed and changes nothing)."""
    if text == "paper":
        return PAPER_KINDS
    if text == "all":
        return ERROR_KINDS
    names = [name.strip() for name in text.split(",")]
    unknown = [name for name in names if name not in ERROR_KINDS]
    if unknown or not text.strip():
        raise ValueError(f"unknown error kind {unknown[0] if unknown else text!r}: 'paper', 'all' or a comma-separated "
                         f"list of {', '.join(ERROR_KINDS)}")
    return tuple(kind for kind in ERROR_KINDS if kind in names or kind in PAPER_KINDS)
