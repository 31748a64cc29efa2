"""The paper's search algorithms: heuristic bisection and random search."""
