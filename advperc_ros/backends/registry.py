"""Backends by name: what `rollout_backend` chooses, imported only when chosen.

A backend is a class `Class(scenario, params, configs=..., bag_path=..., transport=...)` that is a
context manager with the `base.Rollouts` protocol; adding one is one module and one line here (and the
name among the `rollout_backend` choices of `advperc_ros.params`, which a test ties to this table).
"""

import importlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from advperc_ros.backends.base import Rollouts
from advperc_ros.configs import CoreConfigs
from advperc_ros.core.scenario import Scenario
from advperc_ros.params import AttackParams

BACKENDS = {
    "embedded": "advperc_ros.backends.embedded:Stack",
    "graph": "advperc_ros.backends.graph.rollouts:GraphRollouts",
}


def backend_class(name: str) -> type:
    """The class of the backend `name` (imported now: the graph backend's DDS stack only when asked for)."""
    module_name, _, class_name = BACKENDS[name].partition(":")
    return getattr(importlib.import_module(module_name), class_name)


@contextmanager
def open_rollouts(scenario: Scenario, params: AttackParams, bag_path: Path, transport: Any = None,
                  configs: CoreConfigs | None = None) -> Iterator[Rollouts]:
    """The backend `rollout_backend` names, ready to use and shut down on exit. `transport`
    (graph backend, nodes not spawned) lets an rclpy orchestrator reach nodes over its own node;
    `configs`: the params' core configs, when the caller built them."""
    cls = backend_class(params.rollout_backend)
    with cls(scenario, params, configs=configs, bag_path=bag_path, transport=transport) as rollouts:
        yield rollouts
