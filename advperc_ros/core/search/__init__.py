"""The search: the paper's algorithms (heuristic bisection, random search), the phases beyond them (joint
drops, approach, refine) and the guided search; pipeline.py runs them in order."""
