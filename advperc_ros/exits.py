"""Exit codes and the expected failures behind them: one table for `advperc` and every node.

An expected failure is one line on stderr (or the node's log) and its own exit code; anything
else is a bug and keeps its traceback.
"""

from advperc_ros.exceptions import (
    BagError,
    GraphError,
    GroundTruthFails,
    InconclusiveSearch,
    Interrupted,
    OutOfSpace,
    OutputError,
    ParamsError,
    PEMError,
    PluginError,
    ResultsError,
    ScenarioError,
    ScenarioRejected,
)

EXIT_OK = 0
EXIT_NOTHING_TO_ATTACK = 1  # the stack fails with perfect perception, or check-typical found collisions
EXIT_INPUT = 2  # bad input: params, bag, plug-in, results folder read, output folder (one without room for output)
EXIT_REJECTED = 3  # a recording whose traffic hits the ego whatever it does
EXIT_GRAPH = 4  # the node graph could not be started or made ready, or most rollouts were inconclusive
EXIT_INTERRUPTED = 130  # Ctrl-C (128 + SIGINT), as shells report it; an attack's checkpoint is kept

INPUT_ERRORS = (ParamsError, BagError, ScenarioError, PluginError, PEMError, OutputError, ResultsError, OutOfSpace)
EXPECTED: tuple[tuple[tuple[type[BaseException], ...], str, int], ...] = (
    (INPUT_ERRORS, "error: ", EXIT_INPUT),
    ((GroundTruthFails,), "", EXIT_NOTHING_TO_ATTACK),
    ((ScenarioRejected,), "", EXIT_REJECTED),
    ((GraphError,), "error: graph backend: ", EXIT_GRAPH),
    ((InconclusiveSearch,), "error: ", EXIT_GRAPH),
    ((Interrupted,), "interrupted: ", EXIT_INTERRUPTED),
)
EXPECTED_TYPES = tuple(kind for kinds, _, _ in EXPECTED for kind in kinds)


def expected_failure(exc: BaseException) -> tuple[str, int]:
    """(the line to print after the program's name, the exit code) of an `EXPECTED_TYPES` error;
    one line whatever the message holds (a YAML parser's, say, spans several)."""
    prefix, code = next((prefix, code) for kinds, prefix, code in EXPECTED if isinstance(exc, kinds))
    return f"{prefix}{' '.join(str(exc).split())}", code
