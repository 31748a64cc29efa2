"""ROS-free core: scenario, errors, tracker, planners, rules, metrics, rollout, search."""
