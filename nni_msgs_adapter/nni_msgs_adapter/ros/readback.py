"""The read-back: every node states at start the parameters it runs with; its starter compares them with its own.

``node_main`` prints, once a node is made and before it spins, one line per
node on stdout (a composed process: one per node)::

    plant_node parameters: {"node": "/plant", "parameters": {"mode": "lockstep", ...}}

``nni-demo`` and the launch files hold the plant's run (``hold_until_released``)
until every node they started has stated what they passed (:func:`mismatch`
is None), and refuse to start otherwise. Parameters are locked from the start
(:mod:`.ros_params`), so what a node states is what it runs with. Pure Python:
no ROS import.
"""

from __future__ import annotations

import json
import math

#: Between the program's name and the JSON of a parameters line.
PARAMETERS_MARK = " parameters: "


def parameters_line(prog: str, node: str, values: dict) -> str:
    """The line ``prog`` prints for ``node`` (its fully qualified name) and the parameters it runs with."""
    return f"{prog}{PARAMETERS_MARK}{json.dumps({'node': node, 'parameters': values})}"


def stated_parameters(output: str) -> dict[str, dict]:
    """``{node: parameters}`` of every complete parameters line in a process's ``output`` (any program's)."""
    stated = {}
    for line in output.split("\n")[:-1]:  # the last piece is not a whole line yet
        prog, mark, text = line.partition(PARAMETERS_MARK)
        if not mark or " " in prog or not text.startswith("{"):
            continue
        try:
            entry = json.loads(text)
        except ValueError:
            continue
        if isinstance(entry, dict) and isinstance(entry.get("parameters"), dict):
            stated[entry.get("node")] = entry["parameters"]
    return stated


def expected_parameters(specs, passed: dict) -> dict:
    """What a node given ``passed`` must state: its parameter table's defaults (``specs``), then ``passed``."""
    return {**{spec.name: spec.default for spec in specs}, **passed}


def _same(passed, stated) -> bool:
    """Equal as parameter values: numbers by value (an int passed to a double, NaN to NaN), lists item by item."""
    if isinstance(passed, (list, tuple)) and isinstance(stated, (list, tuple)):
        return len(passed) == len(stated) and all(_same(a, b) for a, b in zip(passed, stated))
    if isinstance(passed, float) and isinstance(stated, float) and math.isnan(passed):
        return math.isnan(stated)
    if isinstance(passed, bool) or isinstance(stated, bool):
        return passed is stated
    return passed == stated


def differences(passed: dict, stated: dict) -> list[str]:
    """``name: passed X, runs with Y`` for every passed value the node does not run with."""
    return [f"{name}: passed {value!r}, " + (f"runs with {stated[name]!r}" if name in stated else "not declared")
            for name, value in passed.items() if name not in stated or not _same(value, stated[name])]


def mismatch(passed: dict[str, dict], stated: dict[str, dict]) -> str | None:
    """None when every node of ``passed`` (``{node: parameters}``) stated them all; else one phrase naming the first
    node that did not (a node that stated nothing yet is not judged: the caller waits for it)."""
    for node, values in passed.items():
        if node in stated:
            wrong = differences(values, stated[node])
            if wrong:
                return f"{node} runs with other parameters than it was given ({'; '.join(wrong)})"
    return None


class ReadbackGate:
    """What a launch file's output handlers decide: fed each process's output as it comes, says when to release.

    ``passed``: ``{node: parameters}`` of every node started. :meth:`feed` returns None while a node has
    not stated its parameters yet, :data:`RELEASE` once (when the last one has, and all match), or the
    mismatch phrase (once: the caller shuts down).
    """

    RELEASE = "release"

    def __init__(self, passed: dict[str, dict]):
        self.passed = passed
        self._output: dict[str, str] = {}
        self.decided = False

    def feed(self, source: str, text: str) -> str | None:
        """Output ``text`` of process ``source`` (its name); the decision, if this output made it."""
        if self.decided:
            return None
        self._output[source] = self._output.get(source, "") + text
        stated = {}
        for output in self._output.values():
            stated.update(stated_parameters(output))
        wrong = mismatch(self.passed, stated)
        if wrong is None and not set(self.passed) <= set(stated):
            return None
        self.decided = True
        return wrong or self.RELEASE
