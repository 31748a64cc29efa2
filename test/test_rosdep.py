"""`rosdep install --from-paths src --ignore-src` can succeed: every key of package.xml is either a
ROS package of the kit or defined in rosdep.yaml (the pip-only dependencies have no key in ROS's own
rosdep database), each of rosdep.yaml's keys resolves with rosdep itself, and their pip names are
the ones setup.py installs, so neither file can drift from the other."""

import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest
import yaml

from conftest import REPO

DEPENDS = ("depend", "exec_depend", "build_depend", "test_depend")


def _keys() -> set[str]:
    root = ET.parse(REPO / "package.xml").getroot()
    return {element.text.strip() for tag in DEPENDS for element in root.iter(tag)}


def _ours() -> dict:
    return yaml.safe_load((REPO / "rosdep.yaml").read_text())


def _requirement_names() -> set[str]:
    """The distribution names setup.py installs (requirements.txt and the test extra)."""
    text = (REPO / "setup.py").read_text()
    test = re.findall(r'"([A-Za-z0-9_.\-\[\]]+[<>=][^"]*)"', re.search(r'"test": \[(.*?)\]', text, re.S).group(1))
    return {re.split(r"[<>=\[]", name)[0].lower() for name in (REPO / "requirements.txt").read_text().split() + test}


def test_every_pip_key_installs_what_setup_py_requires():
    pip = {name.lower() for rules in _ours().values() for rule in rules.values() if isinstance(rule, dict)
           for name in rule["pip"]["packages"]}
    assert pip and pip <= _requirement_names(), pip - _requirement_names()


def test_rosdep_itself_resolves_every_key_of_ours(tmp_path):
    """Offline: a rosdistro index of our own making (no ROS packages) and rosdep.yaml as the only source."""
    index, sources = tmp_path / "index", tmp_path / "sources.list.d"
    (index / "jazzy").mkdir(parents=True)
    sources.mkdir()
    (index / "index-v4.yaml").write_text(yaml.safe_dump({"type": "index", "version": 4, "distributions": {"jazzy": {
        "distribution": ["jazzy/distribution.yaml"], "distribution_status": "active", "distribution_type": "ros2",
        "python_version": 3}}}))
    (index / "jazzy" / "distribution.yaml").write_text(yaml.safe_dump({"release_platforms": {"ubuntu": ["noble"]},
                                                                       "repositories": {}, "type": "distribution",
                                                                       "version": 2}))
    (sources / "50-advperc_ros.list").write_text(f"yaml file://{REPO / 'rosdep.yaml'}\n")
    env = dict(os.environ, ROSDEP_SOURCE_PATH=str(sources), ROS_HOME=str(tmp_path / "home"),
               ROSDISTRO_INDEX_URL=(index / "index-v4.yaml").as_uri())
    rosdep = [sys.executable, "-c", "import sys; from rosdep2.main import rosdep_main; rosdep_main(sys.argv[1:])"]
    ran = subprocess.run([*rosdep, "update", "--rosdistro", "jazzy"], env=env, capture_output=True, text=True, timeout=120)
    assert ran.returncode == 0, ran.stdout + ran.stderr
    for key, rules in _ours().items():
        ran = subprocess.run([*rosdep, "resolve", key, "--os=ubuntu:noble", "--rosdistro", "jazzy"], env=env,
                             capture_output=True, text=True, timeout=60)
        assert ran.returncode == 0, ran.stdout + ran.stderr
        rule = rules["ubuntu"]
        installer, *packages = ran.stdout.split()
        expected = ("#pip", rule["pip"]["packages"]) if isinstance(rule, dict) else ("#apt", rule)
        assert (installer, packages) == expected, (key, ran.stdout)


def test_every_key_of_package_xml_is_ours_or_a_ros_package_of_the_kit():
    from conftest import need_ros

    need_ros()
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    def is_ros_package(name: str) -> bool:
        try:
            return bool(get_package_prefix(name))
        except PackageNotFoundError:
            return False

    unknown = sorted(key for key in _keys() - set(_ours()) if not is_ros_package(key))
    assert not unknown, f"package.xml keys neither in rosdep.yaml nor ROS packages of the kit: {unknown}"


def test_the_docs_say_how_to_register_our_keys():
    page = (REPO / "docs" / "ros2.md").read_text()
    assert "rosdep.yaml" in page and "rosdep install --from-paths src --ignore-src" in page
