"""Backends by name: what `rollout_backend` chooses, imported only when chosen.

A backend is a class `Class(scenario, configs, bag_path=..., transport=...)`, built from the attack's
`CoreConfigs` alone, that is a context manager with the `base.Rollouts` protocol; adding one is one
module and one line here (and the name among the `rollout_backend` choices of `advperc_ros.params`,
which a test ties to this table). It is loaded as every plug-in is (`core.plugins`).
"""

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from advperc_ros.backends.base import Rollouts
from advperc_ros.configs import CoreConfigs
from advperc_ros.core.plugins import PluginKind, load
from advperc_ros.core.scenario import Scenario

BACKENDS = {
    "embedded": "advperc_ros.backends.embedded:Stack",
    "graph": "advperc_ros.backends.graph.rollouts:GraphRollouts",
}
ROLLOUT_BACKENDS = PluginKind("rollout backend", BACKENDS, type, "a class", plug_ins=False)


def backend_class(name: str) -> type:
    """The class of the backend `name` (imported now: the graph backend's DDS stack only when asked for)."""
    cls: type = load(name, ROLLOUT_BACKENDS)
    return cls


@contextmanager
def open_rollouts(scenario: Scenario, configs: CoreConfigs, bag_path: Path, transport: Any = None) -> Iterator[Rollouts]:
    """The backend `rollout_backend` names, ready to use and shut down on exit. `transport`
    (graph backend, nodes not spawned) lets an rclpy orchestrator reach nodes over its own node."""
    cls = backend_class(configs.execution.backend)
    with cls(scenario, configs, bag_path=bag_path, transport=transport) as rollouts:
        yield rollouts
