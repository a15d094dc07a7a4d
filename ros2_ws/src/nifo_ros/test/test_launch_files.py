"""The launch files name only what exists: executables (console scripts in setup.py), parameter
files (config/), parameters (declared by the node), remapped topics (the nodes' topics), launch
arguments (declared before use). ``launch``/``launch_ros`` are not needed: the files are parsed
with ``ast``, so this runs under ``colcon test`` and in nifo's own suite alike."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest
import yaml

PKG = Path(__file__).resolve().parents[1]
LAUNCH = sorted((PKG / "launch").glob("*.launch.py"))


def _console_scripts() -> set[str]:
    tree = ast.parse((PKG / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            for k, v in zip(node.keys, node.values):
                if isinstance(k, ast.Constant) and k.value == "console_scripts":
                    return {ast.literal_eval(e).split("=")[0].strip() for e in v.elts}
    raise AssertionError("setup.py declares no console_scripts")


def _kw(call: ast.Call, name: str):
    return next((k.value for k in call.keywords if k.arg == name), None)


def _calls(tree, name: str) -> list[ast.Call]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call)
            and (getattr(n.func, "id", None) == name or getattr(n.func, "attr", None) == name)]


def _yaml_params(path: Path, node: str) -> set[str]:
    doc = yaml.safe_load(path.read_text())
    return set(doc[f"/**/{node}"]["ros__parameters"])


@pytest.mark.parametrize("launch", LAUNCH, ids=[p.name for p in LAUNCH])
def test_launch_file_names_only_existing_executables_files_parameters_and_arguments(launch):
    tree = ast.parse(launch.read_text(), filename=str(launch))
    scripts = _console_scripts()
    declared = {ast.literal_eval(c.args[0]) for c in _calls(tree, "DeclareLaunchArgument")}
    used = {ast.literal_eval(c.args[0]) for c in _calls(tree, "LaunchConfiguration")}
    assert used <= declared, f"{launch.name}: launch arguments used but not declared: {used - declared}"
    nodes = _calls(tree, "Node")
    assert nodes, f"{launch.name} starts no node"
    for call in nodes:
        assert ast.literal_eval(_kw(call, "package")) == "nifo_ros"
        exe = ast.literal_eval(_kw(call, "executable"))
        assert exe in scripts, f"{launch.name}: executable {exe!r} is not a console script of setup.py"
        params = _kw(call, "parameters")
        names: set[str] = set()
        for item in (params.elts if params is not None else []):
            if isinstance(item, ast.Call):  # os.path.join(cfg, "<node>.yaml")
                f = PKG / "config" / ast.literal_eval(item.args[-1])
                assert f.is_file(), f"{launch.name}: parameter file {f.name} does not exist"
                names |= _yaml_params(f, exe)
            elif isinstance(item, ast.Dict):
                over = {ast.literal_eval(k) for k in item.keys}
                assert over <= names, f"{launch.name}: {exe} parameters {over - names} are not in its config file"
        remaps = _kw(call, "remappings")
        for pair in (remaps.elts if remaps is not None else []):
            src, _ = ast.literal_eval(pair)
            assert src.lstrip("/") in _node_topics(), f"{launch.name}: remapped topic {src!r} is not a nifo topic"


def _node_topics() -> set[str]:
    """The nodes' relative topic names, from nifo_nodes.common.TOPICS when installed, else from its source."""
    try:
        from nifo_nodes.common import TOPICS
        return set(TOPICS.values())
    except ImportError:  # the ROS package built alone: nothing to remap against
        pytest.skip("nifo_nodes is not installed into this Python")


def test_every_parameter_file_sets_only_parameters_the_node_declares():
    try:
        import importlib
        mods = {n: importlib.import_module(f"nifo_nodes.{n}") for n in ("acquisition", "integrator", "identifier")}
    except ImportError:
        pytest.skip("nifo_nodes is not installed into this Python")
    for node, mod in mods.items():
        names = _yaml_params(PKG / "config" / f"{node}.yaml", node)
        declared = set(mod.PARAMS)
        assert names <= declared, f"config/{node}.yaml sets undeclared parameters {names - declared}"


def test_package_xml_declares_every_ros_package_the_python_code_imports():
    xml = (PKG / "package.xml").read_text()
    deps = set(re.findall(r"<(?:exec_)?depend>([^<]+)</", xml))
    roots = set()
    for f in [*LAUNCH, *(PKG / "nifo_ros").glob("*.py")]:
        for n in ast.walk(ast.parse(f.read_text())):
            if isinstance(n, ast.ImportFrom) and n.module:
                roots.add(n.module.split(".")[0])
            elif isinstance(n, ast.Import):
                roots |= {a.name.split(".")[0] for a in n.names}
    try:  # the node code itself (the nifo Python package), when installed
        import nifo_nodes
        for f in Path(nifo_nodes.__file__).parent.glob("*.py"):
            for n in ast.walk(ast.parse(f.read_text())):
                if isinstance(n, ast.ImportFrom) and n.module and n.level == 0:
                    roots.add(n.module.split(".")[0])
                elif isinstance(n, ast.Import):
                    roots |= {a.name.split(".")[0] for a in n.names}
    except ImportError:
        pass
    ros = {r for r in roots if r in ("rclpy", "ament_index_python", "launch", "launch_ros")
           or r.endswith(("_msgs", "_srvs", "_interfaces"))}
    assert {"rclpy", "ament_index_python", "launch", "launch_ros"} <= ros
    assert ros <= deps, f"imported but not in package.xml: {ros - deps}"
