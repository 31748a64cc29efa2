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
