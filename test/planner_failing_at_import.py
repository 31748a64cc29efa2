"""A plug-in module that fails as it is imported (test_plugin_faults.py)."""

raise RuntimeError("CUDA not found")
