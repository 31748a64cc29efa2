"""Interface profiles: the message types and topic names the graph speaks to a team's stack.

A profile (`base.Profile`) says, for each layer a team's node may read or write (detections,
tracked objects, the ego, the plan), which topic carries it, in which message type, and how that
type converts to and from the graph's own boxes and plans. `registry` names the bundled ones.
"""
