"""The graph backend: every rollout driven through the node graph, the nodes separate OS processes.

- `rollouts.GraphRollouts`: the backend the search uses (start, warm up, roll out, restart, stop);
- `processes.NodeProcesses`: the node processes it starts and watches;
- `client.LockstepClient`: its side of the lockstep protocol over a transport;
- `assembly`: the RolloutResult built from what the graph published.

What goes wrong (`GraphError`, `RolloutFault`) is in `advperc_ros.exceptions`.
"""
