"""Sphinx configuration of the documentation site: MyST Markdown pages, built offline.

Build it from the repository root (warnings are errors, and a broken link between pages or to a
missing heading is a warning):

    pip install -e '.[docs]' && python -m sphinx -W --keep-going -b html docs docs/_build/html
"""

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS.parent))  # advperc_ros, for autodoc and the generated params table
sys.path.insert(0, str(DOCS / "_ext"))

project = "advperc_ros"
author = "advperc_ros developers"
copyright = "advperc_ros developers"
release = "0.1.0"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "advperc_docs",  # docs/_ext/advperc_docs.py: the params reference generated from the schema
]

source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]

# Every heading up to ### gets an anchor, so `[x](page.md#heading)` is checked: a link to a page or
# a heading that does not exist is a warning, and -W makes it an error.
myst_heading_anchors = 3
myst_enable_extensions = ["colon_fence"]

# Offline: no intersphinx, nothing fetched. Heavy or optional imports are mocked for autodoc.
autodoc_mock_imports = ["rclpy", "ray", "cyclonedds", "commonroad", "commonroad_rp", "launch", "launch_ros"]
autodoc_member_order = "bysource"
autodoc_typehints = "description"

html_theme = "alabaster"
html_title = "advperc_ros"
html_static_path: list[str] = []
