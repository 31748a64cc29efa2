"""Rollout backends: where the system under attack runs, behind one protocol.

- `base`: the protocol the search needs (`Rollouts`) and which planner a backend attacks;
- `registry`: backends by the name `rollout_backend` gives, and `open_rollouts`;
- `embedded`: the stack in this process (`Stack`), with a worker pool for batches;
- `graph/`: the node graph, the nodes separate OS processes over Cyclone DDS;
- `resumed`: a killed attack's checkpoint, answering the rollouts it already ran.

Backends sit above `core` and `ros` and the five graph nodes (`advperc_ros.nodes`, which the graph
backend starts as processes), and below the application layer, which alone chooses one.
"""
