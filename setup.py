"""ament_python package definition; also a plain `pip install .` off ROS."""

from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "advperc_ros"
NODES = ("orchestrator", "scenario_player", "error_injector", "tracker", "planner", "rule_monitor")  # one executable per module in advperc_ros/nodes/, as `ros2 run` names them

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    package_data={PACKAGE: ["py.typed", "data/*.json"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml", "rosdep.yaml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.json")),
        (f"share/{PACKAGE}/scenarios", glob("scenarios/*.yaml")),
        *[(f"share/{PACKAGE}/{bag}", glob(f"{bag}/*")) for bag in glob("bags/*")],
    ],
    python_requires=">=3.10",
    # the runtime dependencies, in requirements.txt so that a venv can take them without a copy of the package
    install_requires=(Path(__file__).parent / "requirements.txt").read_text().split(),
    extras_require={
        "commonroad": ["commonroad-io>=2023.1"],
        # ray pins protobuf>=3.20.3 and commonroad-io protobuf==3.20.2: they cannot share one environment, so
        # the Ray tests run in a venv of their own (.ci/run) and skip, saying so, where ray is missing
        "ray": ["ray>=2.9"],  # advperc campaign's executor ray
        # TUM's sampling-based planner, attacked through advperc_ros.contrib.reactive; it pins commonroad-io<2025
        # (the importer is tested with 2026.1) and Python<3.12, so it too runs in a venv of its own (.ci/run)
        "reactive": ["commonroad-reactive-planner==2025.1"],
        # fiss-planner's four Frenet planners, attacked through advperc_ros.contrib.fiss: numpy only, so it shares
        # the main environment (and the test extra, so that its tests run in CI's main suite)
        "fiss": ["fiss-planner==1.0.0"],
        # the documentation site (docs/conf.py): Sphinx with MyST Markdown, as rosdoc2 on Jazzy builds it
        "docs": ["sphinx>=7.2", "myst-parser>=2.0"],
        # the CI gates on the package's code: pinned, so that a new release's rules cannot fail an unchanged tree
        "lint": ["ruff==0.17.6", "mypy==2.4.1", "types-PyYAML"],
        "test": ["pytest>=7", "pytest-xdist>=3.5", "hypothesis>=6", "shapely>=2.0", "commonroad-io>=2023.1", "colcon-common-extensions>=0.3",
                 "rosdep>=0.25",  # test_rosdep resolves package.xml's keys with rosdep itself
                 "fiss-planner==1.0.0"],
    },
    zip_safe=True,
    maintainer="advperc_ros developers",
    maintainer_email="dev@advperc.invalid",
    description="Adversarial perception error search against motion planners (ROS 2 Jazzy).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "advperc = advperc_ros.cli:main",
            f"orchestrator = {PACKAGE}.orchestrator_node:main",  # an entry point like the CLI, above the backends
            f"launch_plan = {PACKAGE}.launch_plan:main",  # what attack.launch.py starts, decided in our interpreter
            *[f"{node} = {PACKAGE}.nodes.{node}:main" for node in NODES if node != "orchestrator"],
        ],
    },
)
