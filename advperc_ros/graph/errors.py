"""What goes wrong in the graph backend."""


class GraphError(RuntimeError):
    """The graph could not be started or made ready; the text says which node and why."""


class RolloutFault(Exception):
    """A rollout the graph failed to finish (not the planner's verdict)."""
