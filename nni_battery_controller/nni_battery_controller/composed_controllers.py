"""Composed controllers: one controller node per generator namespace, all in one process on one executor.

What a utility would run on one substation computer (issue 14): the controller_node of each namespace in
parameter ``namespaces``, each with its own parameters, parameter services and diagnostics, as if started
alone with ``-r __ns:=<namespace>``. Per-node values come from a params file with one section per node
(``/gen1/controller: ros__parameters: ...``; ``/**/controller`` for what they share); a ``-p`` on the
command line applies to every node. The host node's parameters are locked as every controller's are
(``allow_tuning``; ``namespaces`` is read at start whatever it says), and each node states its own at
start. SIGINT or SIGTERM stops them all cleanly (final diagnostics, last commands acknowledged), as for
one node. The controllers share one reader of ``/clock`` and one of ``/diagnostics``
(:class:`.controller_node.PlantReaders`, under the host node): the plant's lockstep clock and every status
array reach the process once, not once per controller.
"""

from __future__ import annotations

import sys

from rclpy.exceptions import ParameterException
from rclpy.node import Node

from nni_battery_controller import controller_config
from nni_battery_controller.controller_node import ControllerNode, PlantReaders
from nni_msgs_adapter.ros.defaults import controller_defaults
from nni_msgs_adapter.ros.node_main import run_node
from nni_msgs_adapter.ros.ros_params import (
    Spec,
    allow_tuning,
    declared_values,
    effective_values,
    install_validation,
    locked_changes,
)

#: The host node's name (it holds ``namespaces`` and nothing else).
HOST_NAME = "composed_controllers"
NAMESPACES = Spec("namespaces", [], "The generators' absolute namespaces (/gen1, ...): one controller node "
                  "<namespace>/controller each, with the controller_node parameters below.", array_of=str)


def host_parameters() -> tuple[Spec, ...]:
    """The host node's own: ``namespaces`` and the tuning switch (its default the controllers')."""
    return NAMESPACES, allow_tuning(controller_defaults()["allow_tuning"])


def parameters() -> tuple[Spec, ...]:
    """What ``--help`` lists: ``namespaces``, then every controller node's parameters."""
    return (NAMESPACES, *controller_config.parameters())


class HostNode(Node):
    """The node that holds ``namespaces``: locked as the controllers are, and stated at start."""

    def __init__(self):
        super().__init__(HOST_NAME)
        self._specs = host_parameters()
        values = declared_values(self, self._specs)
        self.namespaces = values["namespaces"]
        self.plant = None  # the controllers' shared PlantReaders (compose), under this node
        install_validation(self, self._specs, lambda new: locked_changes(
            values, new, ["namespaces"], "once the node is up (its controllers are made at start)"),
                           lambda prepared: None, values["allow_tuning"])

    def effective_parameters(self) -> dict:
        """What the host runs with (node_main prints it at start, for the read-back)."""
        return effective_values(self, self._specs)

    def close(self) -> None:
        """Before the node goes (node_main calls it once the executor has stopped): the controllers' readers."""
        if self.plant is not None:
            self.plant.destroy()


def compose() -> list[Node]:
    """The host node and one ControllerNode per namespace; ValueError naming the node that cannot start."""
    host = HostNode()
    namespaces = host.namespaces
    if not namespaces:
        raise ValueError("namespaces is empty: give the generators' namespaces, e.g. -p namespaces:=\"['/gen1']\"")
    controller_config.check_namespaces("namespaces", namespaces)
    nodes = [host]
    host.plant = PlantReaders(host)
    for namespace in namespaces:
        try:
            nodes.append(ControllerNode(plant=host.plant, namespace=namespace))
        except (ValueError, ParameterException) as exc:
            raise ValueError(f"{namespace}/controller: {exc}") from None
    return nodes


def main(args=None) -> int:
    """``ros2 run nni_battery_controller composed_controllers``."""
    return run_node(compose, args, prog="composed_controllers")


if __name__ == "__main__":
    sys.exit(main())
