"""The launch files (``launch`` is not on PyPI: the Python one runs against a recording stand-in
of its API, the XML one is parsed): they start the package's ``loss_estimator`` executable with
the installed parameter file."""

from __future__ import annotations

import ast
import sys
import types
import xml.etree.ElementTree as ET
from importlib.metadata import entry_points

import pytest

from helpers import CONFIG, ROOT

LAUNCH = ROOT / "launch"


def test_the_executable_the_launch_files_name_is_installed():
    scripts = {e.name: e.value for e in entry_points(group="console_scripts")}
    assert scripts["loss_estimator"] == "rollergear_ros.ros.node:main"
    setup = (ROOT / "setup.py").read_text()
    assert 'glob("launch/*.launch.py") + glob("launch/*.launch.xml")' in setup and CONFIG.exists()


@pytest.fixture
def launch_api(monkeypatch):
    """Minimal stand-ins for launch, launch_ros and ament_index_python that record what the
    launch file builds."""
    made: dict[str, list] = {"Node": [], "DeclareLaunchArgument": []}

    def recorder(kind):
        def make(*args, **kwargs):
            made[kind].append((args, kwargs))
            return (kind, args, kwargs)
        return make

    modules = {
        "launch": {"LaunchDescription": lambda entities: ("LaunchDescription", entities)},
        "launch.actions": {"DeclareLaunchArgument": recorder("DeclareLaunchArgument")},
        "launch.substitutions": {"LaunchConfiguration": lambda name: ("LaunchConfiguration", name)},
        "launch_ros": {}, "launch_ros.actions": {"Node": recorder("Node")},
        "ament_index_python": {}, "ament_index_python.packages": {
            "get_package_share_directory": lambda pkg: f"/opt/share/{pkg}"},
    }
    for name, attrs in modules.items():
        module = types.ModuleType(name)
        module.__dict__.update(attrs)
        monkeypatch.setitem(sys.modules, name, module)
    return made


def test_the_python_launch_file_starts_loss_estimator_with_the_parameter_file(launch_api):
    source = (LAUNCH / "loss_estimator.launch.py").read_text()
    ast.parse(source)
    namespace: dict = {}
    exec(compile(source, "loss_estimator.launch.py", "exec"), namespace)  # noqa: S102 - the file under test
    description = namespace["generate_launch_description"]()
    assert description[0] == "LaunchDescription"
    (_, node), = launch_api["Node"]
    assert node["package"] == "rollergear_ros" and node["executable"] == "loss_estimator"
    assert node["parameters"] == [("LaunchConfiguration", "params_file")]
    assert node["namespace"] == ("LaunchConfiguration", "namespace")
    args = {a[0]: kw for a, kw in launch_api["DeclareLaunchArgument"]}
    assert args["params_file"]["default_value"] == "/opt/share/rollergear_ros/config/gearbox.yaml"
    assert args["namespace"]["default_value"] == "rollergear"


def test_the_xml_launch_file_starts_loss_estimator_with_the_parameter_file():
    root = ET.parse(LAUNCH / "loss_estimator.launch.xml").getroot()
    assert root.tag == "launch"
    args = {a.get("name"): a.get("default") for a in root.findall("arg")}
    assert args["params_file"] == "$(find-pkg-share rollergear_ros)/config/gearbox.yaml"
    assert args["namespace"] == "rollergear"
    (node,) = root.findall("node")
    assert (node.get("pkg"), node.get("exec"), node.get("namespace")) == ("rollergear_ros", "loss_estimator",
                                                                        "$(var namespace)")
    assert [p.get("from") for p in node.findall("param")] == ["$(var params_file)"]


#: every third-party module the package imports -> its package.xml key (None: pip-only, in the README)
DEPENDENCIES = {
    "rclpy": "rclpy", "std_msgs": "std_msgs", "sensor_msgs": "sensor_msgs", "diagnostic_msgs": "diagnostic_msgs",
    "rosgraph_msgs": "rosgraph_msgs", "rcl_interfaces": "rcl_interfaces", "ament_index_python": "ament_index_python",
    "numpy": "python3-numpy", "scipy": "python3-scipy", "matplotlib": "python3-matplotlib", "yaml": "python3-yaml",
    "tqdm": "python3-tqdm", "mcap": "mcap-ros2-support", "mcap_ros2": "mcap-ros2-support",
    "zstandard": "mcap-ros2-support", "lz4": "mcap-ros2-support", "rosbags": "python3-rosbags-pip",
    "apsw": "python3-rosbags-pip",  # rosbags' SQLite driver, installed with it (its errors are caught)
    "rerun": None, "pyarrow": None, "asammdf": None, "nptdms": None, "dask": None, "fsspec": None,
}


def test_package_xml_declares_every_import_with_keys_rosdep_has():
    import ast as _ast

    stdlib = set(sys.stdlib_module_names) | {"rollergear_ros"}
    imported = set()
    for path in (ROOT / "rollergear_ros").glob("*.py"):
        for node in _ast.walk(_ast.parse(path.read_text())):
            if isinstance(node, _ast.Import):
                imported |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, _ast.ImportFrom) and node.level == 0 and node.module:
                imported.add(node.module.split(".")[0])
    third_party = imported - stdlib
    assert third_party <= set(DEPENDENCIES), f"not declared: {sorted(third_party - set(DEPENDENCIES))}"
    xml = ET.parse(ROOT / "package.xml").getroot()
    keys = {e.text for e in xml if e.tag in ("depend", "exec_depend", "build_depend")}
    assert {k for k in DEPENDENCIES.values() if k} <= keys
    # the only pip keys are ones rosdep has (invented "-pip" keys make `rosdep install` fail)
    assert {k for k in keys if k.endswith("-pip")} == {"python3-rosbags-pip"}
    readme = (ROOT / "docs" / "development.md").read_text()  # the pip-only ones listed, with why
    pip_only = [m for m, k in DEPENDENCIES.items() if k is None]
    for module in pip_only:
        assert {"rerun": "rerun-sdk"}.get(module, module) in readme
    tests = {e.text for e in xml if e.tag == "test_depend"}
    assert tests == {"python3-pytest", "python3-hypothesis"}
