"""Perception quality metrics: NDS, NDS-t and the Table 1 counts."""
