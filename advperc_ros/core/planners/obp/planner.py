"""The ObP planner: each planning call predicts the tracks, lets stage 1 choose the manoeuvre
class, solves stage 2's NLP from it, and answers a failed solve with a fallback plan; its only
state is the previous plan and controls, and the statistics of the rollout. Both stages are pure
functions of what they are given, so a planner keeps the answers of its latest solves (`SolveMemo`)
and answers a planning call it has solved before without solving again."""

import hashlib
import math
import os
import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from advperc_ros.core.planners.base import PlannerStats, PlanningContext, SolveTimes, Trajectory
from advperc_ros.core.planners.obp.config import OBPConfig, Setup
from advperc_ros.core.planners.obp.fallback import FALLBACKS, fallback
from advperc_ros.core.planners.obp.prediction import Obstacle, predict
from advperc_ros.core.planners.obp.stage1 import Reference, Stage1, straight_reference
from advperc_ros.core.planners.obp.stage2 import Stage2, resample
from advperc_ros.core.planners.parameters import config_from_params
from advperc_ros.core.scenario import EgoState

MEMO_SOLVES = 4096  # solves a planner keeps: some 30 rollouts' worth of planning calls, about 16 MB
MEMO_ENV = "ADVPERC_OBP_MEMO"  # "0": keep no solves (every planning call solved, as benchmarks/fork_bench.py's baseline)


@dataclass(frozen=True)
class Solved:
    """What stage 1 and stage 2 made of a planning call: whether the NLP's solve was accepted, the plan and
    controls it gave (None when it failed: the fallback answers, from the tracks and the previous plan), and
    the manoeuvre class stage 1 chose."""

    ok: bool
    plan: Trajectory | None
    controls: np.ndarray | None  # U (2, N)
    label: str


def solve_key(t: float, ego: EgoState, obstacles: list[Obstacle], controls: np.ndarray | None) -> bytes:
    """A digest of everything both stages read: the plan time, the ego's state, the predicted obstacles in the
    order stage 1 meets them (each field) and the previous solve's controls now, which bound the first jerk and
    steering rate. Two calls with one key get the same stage-1 class and the same NLP solve, bit for bit."""
    digest = hashlib.blake2b(digest_size=16)
    digest.update(np.array([t, ego.x, ego.y, ego.yaw, ego.v], dtype=float).tobytes())
    digest.update(b"no controls" if controls is None else np.ascontiguousarray(controls, dtype=float).tobytes())
    for ob in obstacles:
        digest.update(int(ob.id).to_bytes(8, "little", signed=True))
        digest.update(np.array([ob.yaw, ob.a, ob.b, ob.speed_along], dtype=float).tobytes())
        for array in (ob.cx, ob.cy, ob.s, ob.d):
            digest.update(np.ascontiguousarray(array, dtype=float).tobytes())
    return digest.digest()


class SolveMemo:
    """The answers of a planner's latest solves by `solve_key`, least recently used out first. A search's
    rollouts share most planning calls with earlier ones: hiding a car the planner has pruned (behind the
    ego, or off its road) changes the tracks it is handed but not the obstacles it plans around, so every
    frame of that rollout is a call the ground truth made. It is no state of a rollout: `reset`, `snapshot`
    and `restore` leave it alone, and an answer is the same whichever rollout asked first."""

    def __init__(self, entries: int = MEMO_SOLVES) -> None:
        self.entries = entries
        self._solved: OrderedDict[bytes, Solved] = OrderedDict()
        self.hits = self.misses = 0

    def get(self, key: bytes) -> Solved | None:
        found = self._solved.get(key)
        if found is None:
            self.misses += 1
            return None
        self.hits += 1
        self._solved.move_to_end(key)
        return found

    def put(self, key: bytes, solved: Solved) -> None:
        if self.entries <= 0:
            return
        self._solved[key] = solved
        while len(self._solved) > self.entries:
            self._solved.popitem(last=False)


def memo_entries() -> int:
    """The solves a planner keeps, as `MEMO_ENV` asks: unset or "1" MEMO_SOLVES, "0" none. Any other value is
    refused, not taken for either: a benchmark that meant to turn the memo off must not measure it on."""
    value = os.environ.get(MEMO_ENV, "1")
    if value not in ("0", "1"):
        raise ValueError(f"{MEMO_ENV}={value!r}: 0 (keep no solves) or 1 (keep the latest {MEMO_SOLVES})")
    return MEMO_SOLVES if value == "1" else 0


class OBPPlanner:
    """The paper's optimisation-based planner: stage 1 picks a homotopy class and speed profile (LP),
    stage 2 refines it as an NLP, with a fallback when the solve fails; the planner the paper attacks."""

    def __init__(self, context: PlanningContext, **params) -> None:
        self.context = context
        self.config = config_from_params(OBPConfig, params)
        self.setup = Setup.build(self.config, context)
        self.stage1 = Stage1(self.setup)
        self.stage2 = Stage2(self.setup)
        self.memo = SolveMemo(memo_entries())
        self.reset()

    def reset(self) -> None:
        self._last: Trajectory | None = None
        self._last_controls: tuple[float, np.ndarray] | None = None  # (plan time, U (2, N)) of the last solve
        self.failures = 0  # failed NLP solves since the last reset (one rollout)
        self.fallbacks = dict.fromkeys(FALLBACKS, 0)  # which fallback answered them
        self._solve_times = SolveTimes()  # of every planning call, for benchmarks (stats())
        self.last_class = ""  # the manoeuvre class stage 1 chose last

    def stats(self) -> PlannerStats:
        return PlannerStats(failures=self.failures, solve_times=self._solve_times.as_tuple())

    def snapshot(self) -> tuple:
        """What `plan` reads and `stats` reports; the plan and the controls are never changed in place, and
        the solvers keep nothing from one solve to the next."""
        return (self._last, self._last_controls, self.failures, dict(self.fallbacks), self._solve_times.mark(),
                self.last_class)

    def restore(self, state: tuple) -> None:
        self._last, self._last_controls, self.failures, fallbacks, solve_times, self.last_class = state
        self.fallbacks, self._solve_times = dict(fallbacks), SolveTimes.at(solve_times)

    def plan(self, t: float, ego: EgoState, tracks: dict[str, np.ndarray]) -> Trajectory:
        cfg, setup = self.config, self.setup
        last = self._last
        if last is not None and t - last.t[0] < cfg.replan_period - 1e-9 and last.t[-1] >= t + self.context.dt:
            return last
        started = time.perf_counter()
        s0, d0 = (float(v) for v in self.context.route.project(np.array([ego.x, ego.y])))
        v0 = max(float(ego.v), 0.0)
        obstacles = predict(setup, s0, tracks)
        controls = self._controls_at(t)
        key = solve_key(t, ego, obstacles, controls)
        solved = self.memo.get(key)
        if solved is None:
            solved = self._solve(t, ego, s0, d0, v0, obstacles, controls)
            self.memo.put(key, solved)
        self.last_class = solved.label
        if solved.ok:
            assert solved.plan is not None and solved.controls is not None  # an accepted solve has both
            plan = solved.plan
            self._last_controls = (t, solved.controls)
        else:
            self.failures += 1
            plan, kind = fallback(setup, t, ego, tracks, last)
            self.fallbacks[kind] += 1
            self._last_controls = None
        self._last = plan
        self._solve_times.add(time.perf_counter() - started)
        return plan

    def _solve(self, t: float, ego: EgoState, s0: float, d0: float, v0: float, obstacles: list[Obstacle],
               controls: np.ndarray | None) -> Solved:
        """Stage 1's class and stage 2's solve from it; a solve that fails leaves the plan to the fallback."""
        setup, cfg = self.setup, self.config
        ref: Reference | None  # stage 1 finds none when no class is feasible
        if cfg.single_stage:
            ref = straight_reference(setup, s0, d0, v0, cfg.target_speed, "single-stage")
        else:
            ref = self.stage1.reference(s0, d0, v0, obstacles)
            if ref is None:  # no feasible class: warm start on braking in place, the NLP may still succeed
                ref = straight_reference(setup, s0, d0, v0, 0.0, "no-class")
        try:
            ok, X, U = self.stage2.solve(ego, ref, obstacles, controls)
        except RuntimeError:  # CasADi reports an IPOPT error: a failed solve like any other
            ok = False
        if ok:
            return Solved(True, resample(setup, t, X, U), U, ref.label)
        return Solved(False, None, None, ref.label)

    def _controls_at(self, t: float) -> np.ndarray | None:
        """The last solve's controls at time t, which bound the first jerk and steering rate; None
        after a reset or a fallback, or beyond that solve's horizon."""
        if self._last_controls is None:
            return None
        t_ctrl, U_last = self._last_controls
        k = int(math.floor((t - t_ctrl) / self.setup.h + 1e-9))
        return U_last[:, k].copy() if 0 <= k < U_last.shape[1] else None
