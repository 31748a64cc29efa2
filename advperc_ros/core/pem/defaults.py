"""The bundled reference models (`data/default_pem*.json`): which one scores errors of which kinds."""

from functools import lru_cache
from importlib import resources

from advperc_ros.core.pem.model import PEM
from advperc_ros.core.perception_errors import PAPER_KINDS


@lru_cache(maxsize=2)
def _bundled(name: str) -> PEM:
    return PEM.from_json(resources.files("advperc_ros").joinpath(f"data/{name}").read_text(), name)


def default_pem(kinds: tuple[str, ...] = PAPER_KINDS) -> PEM:
    """The shipped reference model for errors of `kinds`: the paper's kinds keep the hand-specified
    model every published PEM LL of them was scored with (default_pem.json), so none moves; any kind
    beyond them gets the model calibrated on a real detector's published statistics, with every term
    (default_pem_extended.json). Each file's `source` says what it is."""
    return _bundled("default_pem.json" if set(kinds) <= set(PAPER_KINDS) else "default_pem_extended.json")
