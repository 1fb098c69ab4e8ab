"""What the loop's nodes (the plants and the controller) do alike in ROS.

:class:`LoopNode`: its parameter table declared and checked at start, locked
from then on unless ``allow_tuning`` (then each change validated on set and
applied after it: :func:`.ros_params.install_validation`), and stated for the
read-back (:meth:`LoopNode.effective_parameters`); its status on ``/diagnostics`` every
second and once more at close; the first messages' cost paid before the first
sample (:func:`.contract.warm_up`). :class:`StampedPublisher`: a per-sample
topic published as its exact bytes (:mod:`.cdr`).
"""

from __future__ import annotations

from rclpy.node import Node

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.ros_params import declared_values, effective_values, install_validation


class StampedPublisher:
    """A per-sample topic's publisher (under ``namespace`` if given): ``publish(stamp_ns, *values)`` sends its bytes.

    ``layout``: its bytes (default: the topic's, :func:`.contract.layout`).
    """

    def __init__(self, node: Node, topic: str, namespace: str = "", layout=None):
        self.layout = layout or contract.layout(topic)
        self.publisher = node.create_publisher(*contract.endpoint(topic, namespace))

    def publish(self, stamp_ns: int, *values) -> None:
        self.publisher.publish(self.layout.pack(stamp_ns, *values))


class LoopNode(Node):
    """A node of the loop. ``initial_values``: its parameters at start (a ValueError names what cannot start).

    A subclass gives :meth:`_validate` (the new full value dict -> what :meth:`_install`
    applies; ValueError to reject the change), :meth:`_install` and :meth:`publish_diagnostics`
    (through :meth:`publish_status`). The executor calls them, only after its ``__init__``.
    """

    def __init__(self, name: str, specs, **kwargs):
        super().__init__(name, **kwargs)
        self._clock = self.get_clock()
        self.specs = specs
        self.initial_values = declared_values(self, specs)
        install_validation(self, specs, self._validate, self._install, self.initial_values["allow_tuning"])
        self._diagnostics = self.create_publisher(*contract.endpoint(contract.TOPIC_DIAGNOSTICS))
        contract.warm_up()
        self.diagnostics_timer = self.create_timer(1.0, self.publish_diagnostics)

    def effective_parameters(self) -> dict:
        """What the node runs with (node_main prints it at start, for the read-back)."""
        return effective_values(self, self.specs)

    def now_ns(self) -> int:
        """The node's ROS clock in integer ns (:func:`.contract.now_ns`)."""
        return contract.now_ns(self._clock)

    def _validate(self, values: dict):
        raise NotImplementedError

    def _install(self, prepared) -> None:
        raise NotImplementedError

    def publish_diagnostics(self):
        raise NotImplementedError

    def publish_status(self, name: str, level: str, message: str, values: dict, hardware_id: str = "") -> None:
        """One status on ``/diagnostics``; ``hardware_id`` "": the node's."""
        self.publish_statuses([(name, level, message, values, hardware_id)])

    def publish_statuses(self, statuses) -> None:
        """Statuses ``(name, level, message, values, hardware_id)`` in one message on ``/diagnostics``
        (:func:`.contract.diagnostics_array`), as diagnostic_updater sends a node's tasks: each reader
        wakes once for them all (a network plant's ten in separate messages to ten controller processes
        held its thread 6-70 ms a second)."""
        own = self.get_fully_qualified_name()
        self._diagnostics.publish(contract.diagnostics_array(
            self.now_ns(), [(name, level, message, values, hardware_id or own)
                            for name, level, message, values, hardware_id in statuses]))

    def close(self) -> None:
        """Final diagnostics before the node goes (node_main calls it, still able to publish)."""
        self.publish_diagnostics()
