"""advperc_ros: search for adversarial perception errors against motion planners."""

__version__ = "0.1.0"
