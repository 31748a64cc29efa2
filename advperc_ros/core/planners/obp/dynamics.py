"""The kinematic bicycle about the box centre, x' = v cos(yaw), y' = v sin(yaw),
yaw' = v tan(steer) / wheelbase, v' = accel, integrated by RK4 in steps of one frame period.
Written once over the few operations it needs, so that the NLP's dynamics constraints (CasADi
symbols, SYMBOLIC) and the plan's poses between the NLP's nodes (floats, NUMERIC) are the same
model with the same arithmetic: the returned plan is the NLP's own trajectory."""

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np


@dataclass(frozen=True)
class Operations:
    """The math one bicycle model is written with: numpy's for simulating, CasADi's for the NLP, so
    both stages integrate exactly the same model."""

    cos: Callable[[Any], Any]
    sin: Callable[[Any], Any]
    tan: Callable[[Any], Any]
    vector: Callable[..., Any]  # the four state rates as one vector


NUMERIC = Operations(math.cos, math.sin, math.tan, lambda *rates: np.array(rates))
SYMBOLIC = Operations(ca.cos, ca.sin, ca.tan, ca.vertcat)


def bicycle_rk4(state, accel, steer, dt: float, wheelbase: float, steps: int, ops: Operations) -> list:
    """The states (x, y, yaw, v) after each of `steps` RK4 steps of dt, accel and steer held."""
    tan_steer = ops.tan(steer)  # once per call: the NLP's graph shares this node, its derivatives with it

    def rate(q):
        return ops.vector(q[3] * ops.cos(q[2]), q[3] * ops.sin(q[2]), q[3] * tan_steer / wheelbase, accel)

    states = []
    for _ in range(steps):
        k1 = rate(state)
        k2 = rate(state + 0.5 * dt * k1)
        k3 = rate(state + 0.5 * dt * k2)
        k4 = rate(state + dt * k3)
        state = state + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        states.append(state)
    return states
