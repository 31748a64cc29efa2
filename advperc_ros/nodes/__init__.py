"""One module per graph node (`graph_nodes.SPECS`); each is a thin wrapper around a core object.

The nodes sit below the backends, which start them as processes by module name; the orchestrator
node, which runs a whole attack, is an entry point like the CLI: `advperc_ros.orchestrator_node`.
"""
