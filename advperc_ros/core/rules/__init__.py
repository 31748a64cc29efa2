"""The rulebook: driving rules as real-valued functions of a rollout, r < 0 a violation.

base.py is the interface (the Rule protocol, what a rule's value is), registry.py lists the rules,
one module per rule; contact.py is the collision rule's fast measure that the rollout itself runs.
"""
