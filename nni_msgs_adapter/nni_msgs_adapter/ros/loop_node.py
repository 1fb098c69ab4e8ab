"""What the loop's nodes (the plants and the controller) do alike in ROS.

:class:`LoopNode`: its parameter table declared and checked at start, locked
from then on unless ``allow_tuning`` (then each change validated on set and
applied after it: :func:`.ros_params.install_validation`), and stated for the
read-back (:meth:`LoopNode.effective_parameters`); its status on ``/diagnostics`` every
second and once more at close; the first messages' cost paid before the first
sample (:func:`.contract.warm_up`). :class:`StampedPublisher`: a per-sample
topic published as its exact bytes (:mod:`.cdr`); :class:`PolledReader`: a topic read when the node needs it,
without waking its executor.
"""

from __future__ import annotations

from rclpy.node import Node

from nni_msgs_adapter.ros import command_auth, contract
from nni_msgs_adapter.ros.ros_params import declared_values, effective_values, install_validation


class StampedPublisher:
    """A per-sample topic's publisher (under ``namespace`` if given): ``publish(stamp_ns, *values)`` sends its bytes.

    ``layout``: its bytes (default: the topic's, :func:`.contract.layout`).

    A sample is packed and sent only while a reader is matched: every per-sample topic is volatile, so
    one that no reader has matched reaches nobody, and a reader that matches later would not get it either.
    The true states and the controller's states are read by recorders and viewers only; without one,
    their 2 N publishes a lockstep sample (about 10 us each on this machine, cold) went nowhere.
    Both calls go to rclpy's C publisher (``Publisher.handle``) directly: the Python wrapper's
    type check and handle guard cost 1.1 us a publish and as much a count (timeit), N times a sample
    at the plant. The nodes publish from their executor's one thread and destroy their publishers only
    after the last publish (node_main: ``close``, then ``destroy_node``), which is what the guard protects.
    """

    def __init__(self, node: Node, topic: str, namespace: str = "", layout=None, key: bytes | None = None,
                 flag: bytes = b""):
        self.layout = layout or contract.layout(topic, sealed=key is not None)
        self.publisher = node.create_publisher(*contract.endpoint(topic, namespace))
        handle = self.publisher.handle
        self._send, self._readers = handle.publish_raw, handle.get_subscription_count
        #: ``key``: the run's; each sample is then sealed (:data:`.contract.SEALS`: the topic's kind, under the key
        #: of its absolute name), ``flag`` first (a measurement's mode, :data:`.command_auth.LOCKSTEP_FLAG`).
        self.signer = None if key is None else command_auth.Signer(key, self.publisher.topic_name,
                                                                   contract.SEALS[topic][0])
        self._flag = flag

    def read(self) -> bool:
        """A reader is matched: what :meth:`publish` would send reaches someone."""
        return self._readers() > 0

    def publish(self, stamp_ns: int, *values) -> None:
        if self._readers():
            if self.signer is None:
                self._send(self.layout.pack(stamp_ns, *values))
            else:
                self._send(self.layout.pack(stamp_ns, *values, self.signer.seal(stamp_ns, *values, flag=self._flag)))


class PolledReader:
    """A node's reader of a contract topic that no executor dispatches: :meth:`latest` takes what has arrived.

    For a value read only when something else happens (the controller's /clock, read at each measurement):
    a subscription would wake the node's executor for every message, and N controllers on a lockstep plant's
    /clock woke N times a sample more than the fan-out floor's echoes (ieee39 separate, alternating A/B: 0.2-2.0 ms
    of the ten controllers' CPU a sample). The reader is rcl's subscription (rclpy's ``_rclpy.Subscription``, which
    ``Node.create_subscription`` wraps and hands to the executor): it is in the ROS graph under its node,
    matched as any reader, depth 1 (only the latest message is kept), with the topic's reliability and
    durability. :meth:`destroy` it before the node.
    """

    def __init__(self, node: Node, topic: str):
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
        from rclpy.qos import HistoryPolicy, QoSProfile
        from rclpy.type_support import check_is_valid_msg_type

        msg_class, name, qos = contract.endpoint(topic)
        latest = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=qos.reliability,
                            durability=qos.durability)
        self._msg_class = msg_class
        check_is_valid_msg_type(msg_class)  # imports its type support, as Node.create_subscription does
        with node.handle:
            self._handle = _rclpy.Subscription(node.handle, msg_class, name,
                                               latest.get_c_qos_profile())

    def latest(self) -> bytes | None:
        """The CDR bytes of the newest message that arrived since the last call, None if none did (one take: the
        reader keeps only the newest)."""
        with self._handle:
            taken = self._handle.take_message(self._msg_class, True)
        return None if taken is None else taken[0]

    def get_publisher_count(self) -> int:
        return self._handle.get_publisher_count()

    def destroy(self) -> None:
        self._handle.destroy_when_not_in_use()


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

    def publish_statuses(self, statuses, stamp_ns: int | None = None) -> None:
        """Statuses ``(name, level, message, values, hardware_id)`` in one message on ``/diagnostics``
        (:func:`.contract.diagnostics_array`), as diagnostic_updater sends a node's tasks: each reader
        wakes once for them all (a network plant's ten in separate messages to ten controller processes
        held its thread 6-70 ms a second)."""
        own = self.get_fully_qualified_name()
        self._diagnostics.publish(contract.diagnostics_array(
            self.now_ns() if stamp_ns is None else stamp_ns, [(name, level, message, values, hardware_id or own)
                            for name, level, message, values, hardware_id in statuses]))

    def close(self) -> None:
        """Final diagnostics before the node goes (node_main calls it, still able to publish)."""
        self.publish_diagnostics()
