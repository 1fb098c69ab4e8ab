"""No import circle (issue 21): the modules of the three packages and of bench/ import one another as a tree.

The graph is read from the source with ``ast``, not by importing (an import
circle that a lazy, function-level import breaks at run time is still a
circle of responsibilities): every ``import a.b`` and ``from a import b``,
at module level and inside functions, relative ones resolved against the
importing module's package. ``from a import b`` where ``a.b`` is a module
is an edge to ``a.b``; otherwise to ``a``. The strongly connected components
of more than one module are the circles; the test names each with one loop
through it, every step with the file and line of its import.
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Folders whose .py files are modules, each named from the folder's parent (bench/ is the package ``bench``).
PACKAGE_DIRS = ("nni_plant_sim/nni_plant_sim", "nni_battery_controller/nni_battery_controller",
                "nni_msgs_adapter/nni_msgs_adapter", "bench")


def module_files(root: Path, package_dirs=PACKAGE_DIRS) -> dict[str, Path]:
    """Dotted module name -> source file, for every .py file below each of ``package_dirs``."""
    modules = {}
    for package_dir in package_dirs:
        top = root / package_dir
        for path in sorted(top.rglob("*.py")):
            parts = path.relative_to(top.parent).with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def imported_names(tree: ast.AST, module: str, is_package: bool):
    """(dotted name, line) of every import in ``tree``, relative ones made absolute; ``from a import b`` as a.b."""
    package = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # level 1 is the importing module's package, each further level one package up
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - node.level + 1] + ([node.module] if node.module else []))
            else:
                base = node.module
            for alias in node.names:
                yield f"{base}.{alias.name}", node.lineno


def import_graph(modules: dict[str, Path]) -> dict[str, dict[str, tuple[Path, int]]]:
    """Module -> {module it imports: (file, line) of the first such import}; only the modules of ``modules``."""
    graph = {}
    for module, path in modules.items():
        edges = {}
        tree = ast.parse(path.read_text(), filename=str(path))
        for name, line in imported_names(tree, module, path.name == "__init__.py"):
            # The longest prefix that is one of ours: a.b.c imports module a.b when c is a name defined in it.
            parts = name.split(".")
            target = next((".".join(parts[:n]) for n in range(len(parts), 0, -1) if ".".join(parts[:n]) in modules),
                          None)
            if target is not None and target != module and line < edges.get(target, (path, math.inf))[1]:
                edges[target] = (path, line)
        graph[module] = edges
    return graph


def strongly_connected(graph: dict[str, dict]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan's algorithm, iterative), each sorted."""
    index, low, on_stack, stack, found = {}, {}, set(), [], []
    counter = 0
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, successors = work[-1]
            for successor in successors:
                if successor not in index:
                    index[successor] = low[successor] = counter
                    counter += 1
                    stack.append(successor)
                    on_stack.add(successor)
                    work.append((successor, iter(sorted(graph[successor]))))
                    break
                if successor in on_stack:
                    low[node] = min(low[node], index[successor])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return found


def loop_through(graph: dict[str, dict], component: list[str]) -> list[str]:
    """One circle inside ``component``, from its first module back to it (breadth-first: a shortest one)."""
    start, members = component[0], set(component)
    came_from = {start: None}
    frontier = [start]
    while frontier:
        following = []
        for node in frontier:
            for successor in sorted(graph[node]):
                if successor == start:
                    path = [start]
                    while node is not None:
                        path.append(node)
                        node = came_from[node]
                    return path[::-1]
                if successor in members and successor not in came_from:
                    came_from[successor] = node
                    following.append(successor)
        frontier = following
    raise AssertionError(f"{component} is not strongly connected")


def circles(root: Path, package_dirs=PACKAGE_DIRS) -> list[str]:
    """One line per import circle: its modules, then one loop with the import that makes each step."""
    modules = module_files(root, package_dirs)
    graph = import_graph(modules)
    lines = []
    for component in strongly_connected(graph):
        loop = loop_through(graph, component)
        steps = " -> ".join(f"{a} ({graph[a][b][0].relative_to(root)}:{graph[a][b][1]})" for a, b in zip(loop, loop[1:]))
        lines.append(f"import circle of {len(component)} modules {component}: {steps} -> {loop[-1]}")
    return lines


def test_no_module_of_the_packages_or_the_bench_is_in_an_import_circle():
    found = circles(ROOT)
    assert not found, "\n".join(found)


def test_the_graph_holds_every_module_and_their_imports():
    """The check reads what is there: every package's modules, and edges where the sources import each other."""
    modules = module_files(ROOT)
    graph = import_graph(modules)
    assert {"nni_plant_sim", "nni_plant_sim.cases", "nni_plant_sim.cases.replicated", "nni_msgs_adapter.ros.contract",
            "nni_battery_controller.law", "bench.__main__", "bench.pingpong"} <= set(modules)
    assert "nni_plant_sim.cases.replicated" in graph["nni_plant_sim.cases"]  # module level, absolute
    assert "bench.pingpong" in graph["bench.common"]  # inside a function


def test_each_form_of_import_is_an_edge_and_a_circle_is_named(tmp_path):
    """A package made up to hold each form of import once; every one closes a circle that the check reports."""
    package = tmp_path / "pkg" / "pkg"
    (package / "sub").mkdir(parents=True)
    sources = {
        "__init__.py": "",
        "a.py": "import pkg.b\n",  # import a.b
        "b.py": "from pkg import c\n",  # from a import submodule
        "c.py": "def later():\n    from .sub import d\n",  # relative, inside a function
        "sub/__init__.py": "",
        "sub/d.py": "from ..a import NAME\n",  # relative two levels up, a name: an edge to its module
        "e.py": "from pkg.a import NAME\nimport numpy\n",  # into the circle, not part of it; outside: no edge
    }
    for name, text in sources.items():
        (package / name).write_text(text)
    found = circles(tmp_path, ("pkg/pkg",))
    assert found == ["import circle of 4 modules ['pkg.a', 'pkg.b', 'pkg.c', 'pkg.sub.d']: "
                     "pkg.a (pkg/pkg/a.py:1) -> pkg.b (pkg/pkg/b.py:1) -> pkg.c (pkg/pkg/c.py:2) -> "
                     "pkg.sub.d (pkg/pkg/sub/d.py:1) -> pkg.a"]


#: The packages from the bottom up: each may import only those before it (bench/, on top, may import all three).
LAYERS = ("nni_msgs_adapter", "nni_plant_sim", "nni_battery_controller", "bench")


def upward_imports(root: Path, package_dirs=PACKAGE_DIRS, layers=LAYERS) -> list[str]:
    """One line per import of a module from a package above the importer's, with its file and line."""
    modules = module_files(root, package_dirs)
    rank = {package: n for n, package in enumerate(layers)}
    lines = []
    for module, edges in sorted(import_graph(modules).items()):
        for target, (path, line) in sorted(edges.items()):
            low, high = module.partition(".")[0], target.partition(".")[0]
            if rank[high] > rank[low]:
                lines.append(f"{module} ({path.relative_to(root)}:{line}) imports {target}, "
                             f"but {low} sits below {high}")
    return lines


def test_every_package_imports_only_those_below_it():
    found = upward_imports(ROOT)
    assert not found, "\n".join(found)


def test_an_import_up_the_layers_is_named(tmp_path):
    """Two made-up layers: the lower one's function-level import of the upper one is reported, the other way not."""
    for package, text in {"low": "def later():\n    from high import up\n", "high": "from low import down\n"}.items():
        (tmp_path / package / package).mkdir(parents=True)
        (tmp_path / package / package / "__init__.py").write_text("")
        (tmp_path / package / package / "core.py").write_text(text)
    found = upward_imports(tmp_path, ("low/low", "high/high"), ("low", "high"))
    assert found == ["low.core (low/low/core.py:2) imports high, but low sits below high"]
