"""Motion planners and the plug-in protocol they share.

base.py        the interface: Trajectory, PlanningContext, Planner, PlannerStats
registry.py    load_planner: bundled planners by name, plug-ins as module:Class
parameters.py  the bundled planners' rule for parameter kinds and ranges
idm.py         IDM path-following planner
obp/           two-stage optimisation-based planner
"""
