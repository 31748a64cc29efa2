"""Plug-in planners with the faults a team's planner has in its first week (test_plugin_faults.py)."""

from advperc_ros.core.planners.idm import IDMPlanner


class FailsToConstruct(IDMPlanner):
    def __init__(self, context, **params):
        raise RuntimeError("no licence server")


class FailsToReset(IDMPlanner):
    built = False

    def __init__(self, context, **params):
        super().__init__(context, **params)  # which resets once
        self.built = True

    def reset(self):
        if self.built:
            raise KeyError("map not loaded")
        super().reset()


class ReturnsNothing(IDMPlanner):
    def plan(self, t, ego, tracks):
        return None


class Exits(IDMPlanner):
    def plan(self, t, ego, tracks):
        raise SystemExit(3)


FAULTS = (RuntimeError("driver crashed"), ValueError("bad lanelet"), MemoryError(), ZeroDivisionError("dt"),
          AttributeError("'NoneType' object has no attribute 'pose'"), RecursionError(), OSError(5, "I/O error"))
WRONG_PLANS = (None, 0, "trajectory", [], {"x": [1.0]})


class FaultAt(IDMPlanner):
    """The IDM planner with one fault, chosen by its planner_params (the fuzz suite draws them): in
    `fault_phase` 0 construction, 1 reset, 2 plan; from call `fault_after` of that phase on (each
    rollout resets once and plans once a frame, so later calls are later rollouts and frames);
    `fault_kind` 0 raises FAULTS[fault_index], 1 returns WRONG_PLANS[fault_index] from plan, 2 calls
    sys.exit(fault_index)."""

    def __init__(self, context, fault_phase: int = 0, fault_kind: int = 0, fault_index: int = 0, fault_after: int = 0,
                 **params):
        self.fault = (int(fault_phase), int(fault_kind), int(fault_index), int(fault_after))
        self.calls = [0, 0, 0]
        self.built = False
        self._strike(0)
        super().__init__(context, **params)
        self.built = True

    def _strike(self, phase: int, value: object = None) -> object:
        fault_phase, kind, index, after = self.fault
        self.calls[phase] += 1
        if phase != fault_phase or self.calls[phase] <= after:
            return value
        if kind == 2:
            raise SystemExit(index)
        if kind == 1 and phase == 2:
            return WRONG_PLANS[index % len(WRONG_PLANS)]
        raise FAULTS[index % len(FAULTS)]

    def reset(self):
        if self.built:  # IDMPlanner's constructor resets once: that is construction, not a rollout's reset
            self._strike(1)
        super().reset()

    def plan(self, t, ego, tracks):
        return self._strike(2, super().plan(t, ego, tracks))
