"""The ObP planner: each planning call predicts the tracks, lets stage 1 choose the manoeuvre
class, solves stage 2's NLP from it, and answers a failed solve with a fallback plan; its only
state is the previous plan and controls, and the statistics of the rollout."""

import math
import time

import numpy as np

from advperc_ros.core.planners.base import PlannerStats, PlanningContext, Trajectory
from advperc_ros.core.planners.obp.config import OBPConfig, Setup
from advperc_ros.core.planners.obp.fallback import FALLBACKS, fallback
from advperc_ros.core.planners.obp.prediction import predict
from advperc_ros.core.planners.obp.stage1 import Reference, Stage1, straight_reference
from advperc_ros.core.planners.obp.stage2 import Stage2, resample
from advperc_ros.core.planners.parameters import config_from_params
from advperc_ros.core.scenario import EgoState


class OBPPlanner:
    """The paper's optimisation-based planner: stage 1 picks a homotopy class and speed profile (LP),
    stage 2 refines it as an NLP, with a fallback when the solve fails; the planner the paper attacks."""

    def __init__(self, context: PlanningContext, **params) -> None:
        self.context = context
        self.config = config_from_params(OBPConfig, params)
        self.setup = Setup.build(self.config, context)
        self.stage1 = Stage1(self.setup)
        self.stage2 = Stage2(self.setup)
        self.reset()

    def reset(self) -> None:
        self._last: Trajectory | None = None
        self._last_controls: tuple[float, np.ndarray] | None = None  # (plan time, U (2, N)) of the last solve
        self.failures = 0  # failed NLP solves since the last reset (one rollout)
        self.fallbacks = dict.fromkeys(FALLBACKS, 0)  # which fallback answered them
        self._solve_times: list[float] = []  # s per planning call, for benchmarks (stats())
        self.last_class = ""  # the manoeuvre class stage 1 chose last

    def stats(self) -> PlannerStats:
        return PlannerStats(failures=self.failures, solve_times=tuple(self._solve_times))

    def snapshot(self) -> tuple:
        """What `plan` reads and `stats` reports; the plan and the controls are never changed in place, and
        the solvers keep nothing from one solve to the next."""
        return (self._last, self._last_controls, self.failures, dict(self.fallbacks), tuple(self._solve_times),
                self.last_class)

    def restore(self, state: tuple) -> None:
        self._last, self._last_controls, self.failures, fallbacks, solve_times, self.last_class = state
        self.fallbacks, self._solve_times = dict(fallbacks), list(solve_times)

    def plan(self, t: float, ego: EgoState, tracks: dict[str, np.ndarray]) -> Trajectory:
        cfg, setup = self.config, self.setup
        last = self._last
        if last is not None and t - last.t[0] < cfg.replan_period - 1e-9 and last.t[-1] >= t + self.context.dt:
            return last
        started = time.perf_counter()
        s0, d0 = (float(v) for v in self.context.route.project(np.array([ego.x, ego.y])))
        v0 = max(float(ego.v), 0.0)
        obstacles = predict(setup, s0, tracks)
        ref: Reference | None  # stage 1 finds none when no class is feasible
        if cfg.single_stage:
            ref = straight_reference(setup, s0, d0, v0, cfg.target_speed, "single-stage")
        else:
            ref = self.stage1.reference(s0, d0, v0, obstacles)
            if ref is None:  # no feasible class: warm start on braking in place, the NLP may still succeed
                ref = straight_reference(setup, s0, d0, v0, 0.0, "no-class")
        self.last_class = ref.label
        try:
            ok, X, U = self.stage2.solve(ego, ref, obstacles, self._controls_at(t))
        except RuntimeError:  # CasADi reports an IPOPT error: a failed solve like any other
            ok = False
        if ok:
            plan = resample(setup, t, X, U)
            self._last_controls = (t, U)
        else:
            self.failures += 1
            plan, kind = fallback(setup, t, ego, tracks, last)
            self.fallbacks[kind] += 1
            self._last_controls = None
        self._last = plan
        self._solve_times.append(time.perf_counter() - started)
        return plan

    def _controls_at(self, t: float) -> np.ndarray | None:
        """The last solve's controls at time t, which bound the first jerk and steering rate; None
        after a reset or a fallback, or beyond that solve's horizon."""
        if self._last_controls is None:
            return None
        t_ctrl, U_last = self._last_controls
        k = int(math.floor((t - t_ctrl) / self.setup.h + 1e-9))
        return U_last[:, k].copy() if 0 <= k < U_last.shape[1] else None
