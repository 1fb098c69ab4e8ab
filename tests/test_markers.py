"""The suite's markers mean what they say: ``core`` tests start no node and load no ROS; one ``smoke`` test is distributed.

``./scripts/test --quick`` runs ``core or smoke`` for the inner loop, so a slow or ROS-bound test marked
``core`` by mistake would make it neither quick nor pure.
"""

from __future__ import annotations

import ast
from pathlib import Path

import conftest

TESTS = Path(__file__).resolve().parent
#: What a core test module may not import: the ROS test helpers, rclpy, the process supervisor, launch.
ROS_MODULES = ("rosproc", "rclpy", "nni_msgs_adapter.ros.processes", "launch", "launch_ros")


def imported(path: Path) -> set[str]:
    """The modules a test module imports (``import a.b``, ``from a.b import c``), anywhere in it."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def module_marks(path: Path) -> str:
    """The source of a test module's ``pytestmark = ...`` (empty without one)."""
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "pytestmark" for t in node.targets):
            return ast.unparse(node.value)
    return ""


def test_every_core_module_exists_and_imports_no_ros():
    for name in sorted(conftest.CORE_TEST_MODULES):
        path = TESTS / f"{name}.py"
        assert path.exists(), f"conftest.CORE_TEST_MODULES names {name}, which is not a test module"
        used = sorted(module for module in imported(path)
                      if any(module == ros or module.startswith(ros + ".") for ros in ROS_MODULES))
        assert not used, f"{name} is marked core but imports {', '.join(used)}"
        assert "pytest.mark.ros" not in module_marks(path), f"{name} is marked both core and ros"


def smoke_tests() -> list[str]:
    """``module::test`` of every test decorated with ``pytest.mark.smoke``."""
    found = []
    for path in sorted(TESTS.glob("test_*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and any(
                    ast.unparse(decorator) == "pytest.mark.smoke" for decorator in node.decorator_list):
                found.append(f"{path.stem}::{node.name}")
    return found


def test_there_is_one_smoke_test_and_it_runs_the_loop_over_dds():
    (smoke,) = smoke_tests()
    module = smoke.split("::")[0]
    assert module not in conftest.CORE_TEST_MODULES
    assert "pytest.mark.ros" in module_marks(TESTS / f"{module}.py"), f"{smoke} is not a ros test"
