"""Two-stage optimisation-based planner (ObP), after Eiras et al. 2021, "A two-stage
optimisation-based motion planner for safe urban driving". Formulation and rationale: docs/obp.md.

config.py     public parameters, internal constants, and what follows from them (Setup)
road.py       the drivable band around the route
prediction.py constant-velocity predictions of the tracks and their ellipses
stage1.py     the manoeuvre class: homotopy classes, a HiGHS speed LP each
stage2.py     the kinematic-bicycle NLP (CasADi, IPOPT) and the plan at the frame period
fallback.py   the plan that answers a failed solve
planner.py    OBPPlanner: the planner protocol over the above
"""

from advperc_ros.core.planners.obp.planner import OBPPlanner

__all__ = ["OBPPlanner"]
