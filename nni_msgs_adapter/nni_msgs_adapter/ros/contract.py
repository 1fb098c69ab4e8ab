"""The message contract: topic names, QoS, and conversions to common_interfaces messages.

Every node, the logger, replay and the tests take names and QoS from here, so the
contract is defined once. Topic names are relative: start a generator's nodes in
a namespace (``--ros-args -r __ns:=/gen1``) and its topics follow. Message types
are common_interfaces only (no custom .msg: the pip path cannot build them).

Mapping (see README, "Topics"):

* ``pmu`` sensor_msgs/JointState, joint "rotor": position = rotor angle delta
  (rad, against the infinite bus), velocity = speed deviation omega - omega0
  (rad/s), effort = electrical power P_E (pu). Stamp = measurement instant.
* ``c37118/pmu``: the same measurement as read from an IEEE C37.118.2 stream by
  the PDC client node (:mod:`nni_msgs_adapter.c37118.client_node`): position =
  the EMF phasor's angle unwrapped, velocity = 2 pi (FREQ - FNOM), effort = the
  P_E analog; stamp = the frame's SOC/FRACSEC (lockstep: the epoch taken off).
  A controller reads it instead of ``pmu`` with ``measurement_topic``.
* ``battery/command`` sensor_msgs/JointState, joint "battery": effort = battery
  power change P_ST (pu). Stamp = stamp of the measurement it answers.
  header.frame_id = ``battery|hmac-sha256|<sequence>|<MAC>`` from a controller
  with a key (:mod:`.command_auth`: the sequence number in 16 hex digits, the
  HMAC-SHA256 of the tag, the topic, the sequence, the stamp and the power in
  64; 101 characters in all, so that the bytes keep one layout), ``battery``
  from one without (the plant's ``command_authentication none``).
* ``plant/state`` sensor_msgs/JointState, joint "rotor": true delta, speed
  deviation, and effort = battery power P_ST acting on the rotor (pu), at each
  reporting instant (noise-free, for analysis).
* ``controller/state`` sensor_msgs/JointState, one "joint" per internal signal,
  values in ``position``: angle_dev (the d = delta - delta_bar the law used, rad),
  x3 (pu), w (pu), battery_power (pu), saturated (0/1), w_hat (pu rad),
  battery_limit (pu, may be inf). Stamp = the measurement it answers.
* ``plant/invariant_set`` geometry_msgs/PolygonStamped, latched: boundary of the
  invariant set Omega in the (angle deviation rad, speed deviation rad/s) plane.
* ``/diagnostics`` diagnostic_msgs/DiagnosticArray: loop health and counters. Absolute, as ROS
  tools (diagnostic aggregator, rqt_robot_monitor) expect: one topic for every generator, the
  generator's namespace in each status's name (``gen1/plant``; ``plant`` in the root namespace)
  and its hardware_id (the node's fully qualified name, ``/gen1/plant``). The plant's status
  carries ``run_ended`` (:data:`RUN_ENDED`): ``True`` once its run has ended normally (its
  duration reached, or the plant stopped), published at that instant; no measurement follows.
  The silence after it is no loss of data: the controller logs it at INFO and commands nothing
  (:func:`plant_run_ended`).
* ``/clock`` rosgraph_msgs/Clock in lockstep mode (absolute: one simulated clock).
* ``plant/start_fault`` std_srvs/Trigger service: start the fault scenario now.
"""

from __future__ import annotations

import math
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point32, PolygonStamped
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from nni_msgs_adapter.ros import cdr, command_auth

TOPIC_PMU = "pmu"
TOPIC_C37118_PMU = "c37118/pmu"
TOPIC_BATTERY_COMMAND = "battery/command"
TOPIC_PLANT_STATE = "plant/state"
TOPIC_CONTROLLER_STATE = "controller/state"
TOPIC_INVARIANT_SET = "plant/invariant_set"
TOPIC_DIAGNOSTICS = "/diagnostics"
TOPIC_CLOCK = "/clock"
SERVICE_START_FAULT = "plant/start_fault"

ROTOR_JOINT = "rotor"
BATTERY_JOINT = "battery"
#: header.frame_id of the rotor's messages (pmu, plant/state), the command and the controller's state.
ROTOR_FRAME, BATTERY_FRAME, CONTROLLER_FRAME = "generator", "battery", "controller"
#: header.frame_id of an authenticated command: this, then its seal (:mod:`.command_auth`, fixed length).
SEALED_BATTERY_FRAME = f"{BATTERY_FRAME}|{command_auth.SCHEME}|"
#: The same for the plant's measurements and true states, and the controller's state (:func:`seal_of`).
SEALED_ROTOR_FRAME = f"{ROTOR_FRAME}|{command_auth.SCHEME}|"
SEALED_CONTROLLER_FRAME = f"{CONTROLLER_FRAME}|{command_auth.SCHEME}|"
#: The kind of seal (:data:`.command_auth.KINDS`) each sealed topic carries, and the length of its seal.
SEALS = {TOPIC_PMU: ("measurement", command_auth.MEASUREMENT_SEAL_LENGTH),
         TOPIC_C37118_PMU: ("measurement", command_auth.MEASUREMENT_SEAL_LENGTH),
         TOPIC_BATTERY_COMMAND: ("command", command_auth.SEAL_LENGTH),
         TOPIC_PLANT_STATE: ("state", command_auth.SEAL_LENGTH),
         TOPIC_CONTROLLER_STATE: ("state", command_auth.SEAL_LENGTH)}
CONTROLLER_SIGNALS = ("angle_dev", "x3", "w", "battery_power", "saturated", "w_hat", "battery_limit")

#: History depth of every per-sample stream, at the writers and at the subscribers that
#: must keep every message (the MCAP logger, the Rerun bridge, the tests' probes). The
#: lockstep plant waits for the controller only, never for a recorder, so a recorder whose
#: callbacks fall behind must find the backlog still there: a reliable KEEP_LAST writer
#: drops its oldest samples once ``depth`` of them are unacknowledged, whatever the reader's
#: depth. Measured: with depth 100 at the writers, one `nni-demo --b 0.3` lockstep run on a
#: loaded 2-core machine recorded 309 of 500 measurements (one 192-sample hole on every
#: topic); with depth 100 at a probe, 87 to 151 of 501 states were lost. 10,000 samples is
#: 10 s at 1000 frames/s, about 1 MB per topic at most.
RECORDER_DEPTH = 10_000

# Every per-sample stream (measurements, commands, states): RELIABLE because the
# lockstep handshake needs every sample answered, a lost command is a missed
# control action and the recording must be complete; on localhost reliability
# costs no round trip unless a sample is lost. KEEP_LAST RECORDER_DEPTH bounds memory
# while letting a subscriber that stalls (the logger on a busy disk or a loaded
# machine) catch up with nothing lost; the controller itself never has more than one
# sample outstanding. VOLATILE because an old sample is worthless to a controller
# that (re)starts.
SAMPLE_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=RECORDER_DEPTH,
    reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE,
)
# Description published once and kept for late joiners (logger, viewers): latched.
LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1,
    reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
# Diagnostics as ROS tools expect them: reliable, volatile, a small queue.
DIAGNOSTICS_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=10,
    reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE,
)
# /clock: nodes only need the latest time, but the recording should hold every
# tick, so the samples' depth; RELIABLE offered so both reliable and
# best-effort (rclpy's TimeSource) subscribers match.
CLOCK_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=RECORDER_DEPTH,
    reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE,
)

#: topic -> (message type name, message class, QoS), everything the logger records.
TOPICS = {
    TOPIC_PMU: ("sensor_msgs/msg/JointState", JointState, SAMPLE_QOS),
    TOPIC_C37118_PMU: ("sensor_msgs/msg/JointState", JointState, SAMPLE_QOS),
    TOPIC_BATTERY_COMMAND: ("sensor_msgs/msg/JointState", JointState, SAMPLE_QOS),
    TOPIC_PLANT_STATE: ("sensor_msgs/msg/JointState", JointState, SAMPLE_QOS),
    TOPIC_CONTROLLER_STATE: ("sensor_msgs/msg/JointState", JointState, SAMPLE_QOS),
    TOPIC_INVARIANT_SET: ("geometry_msgs/msg/PolygonStamped", PolygonStamped, LATCHED_QOS),
    TOPIC_DIAGNOSTICS: ("diagnostic_msgs/msg/DiagnosticArray", DiagnosticArray, DIAGNOSTICS_QOS),
    TOPIC_CLOCK: ("rosgraph_msgs/msg/Clock", Clock, CLOCK_QOS),
}




def endpoint(topic: str, namespace: str = "") -> tuple:
    """``(message class, topic, QoS)``: the arguments of create_publisher / create_subscription.

    ``namespace`` (``/gen1`` or ``gen1``; ``""``: the node's own) puts a relative topic under a
    generator's namespace: ``/gen1/pmu``.
    """
    _, msg_class, qos = TOPICS[topic]
    return msg_class, (f"/{namespace.strip('/')}/{topic}" if namespace else topic), qos


def recorder_endpoint(topic: str) -> tuple:
    """As :func:`endpoint`, for a subscriber that must keep every message: at least ``RECORDER_DEPTH`` deep."""
    msg_class, name, qos = endpoint(topic)
    deep = QoSProfile(history=qos.history, depth=max(qos.depth, RECORDER_DEPTH), reliability=qos.reliability,
                      durability=qos.durability)
    return msg_class, name, deep


def subscribe(node, topic: str, callback, namespace: str = "", raw: bool = False):
    """A subscription of ``node`` to a contract topic, with the contract's QoS; under ``namespace`` if given.

    ``raw``: the callback gets the message's CDR bytes (for :func:`pmu_from_bytes`, :func:`command_from_bytes`).
    """
    msg_class, name, qos = endpoint(topic, namespace)
    return node.create_subscription(msg_class, name, callback, qos, raw=raw)


class ContractError(ValueError):
    """A message that does not follow the contract (wrong joints, sizes or values)."""


def log_at(logger, level: str, text: str) -> None:
    """Log ``text`` at ``level`` ("info", "warning" or "error"): rclpy fixes one severity per call site."""
    if level == "error":
        logger.error(text)
    elif level == "warning":
        logger.warning(text)
    else:
        logger.info(text)


#: Name of a publisher the ROS graph lists but cannot name yet.
UNNAMED_WRITER = "(a node not yet named in the ROS graph)"


def writers_on(node, topic: str, matched: int) -> tuple[dict[bytes, str], int]:
    """``({GID: node name}, unlisted)``: the publishers on ``topic`` (resolved name) in ``node``'s ROS graph.

    ``matched``: how many publishers a subscription of ``node`` has matched;
    ``unlisted``: how many of them the graph does not list yet (someone all the
    same). A listed one whose node is not named yet is :data:`UNNAMED_WRITER`.
    """
    writers = {bytes(info.endpoint_gid): UNNAMED_WRITER if info.node_name == "_NODE_NAME_UNKNOWN_"
               else f"{info.node_namespace.rstrip('/')}/{info.node_name}"
               for info in node.get_publishers_info_by_topic(topic)}
    return writers, max(0, matched - len(writers))


def now_ns(clock) -> int:
    """``clock.now().nanoseconds`` of a node's ROS clock, without building a Time.

    While ROS time is inactive (no ``use_sim_time``) rcl's ROS clock is the system
    clock, which ``time.time_ns`` reads: 0.1 us (0.8 with the check) against 2.6 us
    for ``now()``, which measured 10 us on the lockstep loop's critical path, where
    the plant and the controller each read it for every sample.
    """
    return clock.now().nanoseconds if clock.ros_time_is_active else time.time_ns()


def time_from_ns(stamp_ns: int) -> Time:
    """builtin_interfaces/Time from integer nanoseconds."""
    return Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)


def ns_from_time(stamp: Time) -> int:
    """Integer nanoseconds from builtin_interfaces/Time."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def pmu_message(stamp_ns: int, delta_rad: float, speed_rad_s: float, p_elec_pu: float,
                seal: bytes | None = None) -> JointState:
    """A PMU measurement as JointState (see module docstring for the mapping); ``seal``: its authentication."""
    msg = JointState(name=[ROTOR_JOINT], position=[float(delta_rad)], velocity=[float(speed_rad_s)],
                     effort=[float(p_elec_pu)])
    msg.header.stamp = time_from_ns(stamp_ns)
    msg.header.frame_id = ROTOR_FRAME if seal is None else SEALED_ROTOR_FRAME + seal.decode()
    return msg


def rotor_bytes(seal_length: int = 0) -> cdr.StampedBytes:
    """The bytes of :func:`pmu_message` and :func:`plant_state_message`: ``pack(stamp_ns, delta, speed, effort)``,
    with a seal of ``seal_length`` bytes (0: none) its last value.

    For the plant, which publishes them at every sample (:mod:`.cdr`: the same bytes, without
    building a message; tests/test_cdr.py).
    """
    if seal_length:
        return cdr.joint_state(SEALED_ROTOR_FRAME, (ROTOR_JOINT,), (1, 1, 1), seal_length)
    return cdr.joint_state(ROTOR_FRAME, (ROTOR_JOINT,), (1, 1, 1))


def pmu_from_message(msg: JointState) -> tuple[int, float, float]:
    """``(stamp_ns, delta rad, speed deviation rad/s)``; ContractError if malformed (values unchecked: the gate's job)."""
    _expect_joint(msg, ROTOR_JOINT)
    return ns_from_time(msg.header.stamp), msg.position[0], msg.velocity[0]


def command_message(stamp_ns: int, battery_power_pu: float, seal: bytes | None = None) -> JointState:
    """A battery power command; ``stamp_ns`` is the answered measurement's stamp, ``seal`` its authentication."""
    msg = JointState()
    msg.header.stamp = time_from_ns(stamp_ns)
    msg.header.frame_id = BATTERY_FRAME if seal is None else SEALED_BATTERY_FRAME + seal.decode()
    msg.name = [BATTERY_JOINT]
    msg.effort = [float(battery_power_pu)]
    return msg


def command_bytes(sealed: bool = False) -> cdr.StampedBytes:
    """The bytes of :func:`command_message`: ``pack(stamp_ns, battery_power_pu)``, ``sealed``: and the seal."""
    if sealed:
        return cdr.joint_state(SEALED_BATTERY_FRAME, (BATTERY_JOINT,), (0, 0, 1), command_auth.SEAL_LENGTH)
    return cdr.joint_state(BATTERY_FRAME, (BATTERY_JOINT,), (0, 0, 1))


def command_from_message(msg: JointState) -> tuple[int, float]:
    """``(answered stamp_ns, battery power pu)``; ContractError if malformed."""
    if list(msg.name) != [BATTERY_JOINT] or len(msg.effort) != 1:
        raise ContractError(f"battery command must carry one joint {BATTERY_JOINT!r} with one effort")
    return ns_from_time(msg.header.stamp), msg.effort[0]


def command_seal(msg: JointState) -> bytes | None:
    """The seal a command carries in its frame_id (checked by :func:`.command_auth.CommandVerifier`), None if none."""
    return frame_seal(msg.header.frame_id, SEALED_BATTERY_FRAME)


#: The layouts the loop's nodes publish, to read back without building a message (:meth:`cdr.StampedBytes.unpack`).
_ROTOR_LAYOUT, _COMMAND_LAYOUT, _SEALED_LAYOUT = rotor_bytes(), command_bytes(), command_bytes(sealed=True)
_SEALED_PMU_LAYOUT = rotor_bytes(command_auth.MEASUREMENT_SEAL_LENGTH)
_CLOCK_LAYOUT = cdr.clock()


def _deserialised(data: bytes, msg_class):
    try:
        return deserialize_message(data, msg_class)
    except Exception as error:  # rclpy raises its RMWError for bytes that are no such message
        raise ContractError(f"not a {msg_class.__name__}: {error}") from None


def pmu_from_bytes(data: bytes) -> tuple[tuple[int, float, float], tuple, bytes | None]:
    """``(pmu_from_message's reading, the efforts, the seal or None)`` of a measurement received as bytes;
    ContractError if malformed.

    The plant's own layouts (:func:`rotor_bytes`, sealed or not) are read in place (measured: 1.8 us against
    17 us for rclpy's deserialisation, on the controller's path at every sample); any other bytes are
    deserialised by rclpy and judged as a message.
    """
    fast = _SEALED_PMU_LAYOUT.unpack(data)
    if fast is not None:
        stamp_ns, (delta, speed, p_elec, seal) = fast
        return (stamp_ns, delta, speed), (p_elec,), seal
    fast = _ROTOR_LAYOUT.unpack(data)
    if fast is not None:
        stamp_ns, (delta, speed, p_elec) = fast
        return (stamp_ns, delta, speed), (p_elec,), None
    msg = _deserialised(data, JointState)
    return pmu_from_message(msg), tuple(msg.effort), frame_seal(msg.header.frame_id, SEALED_ROTOR_FRAME)


def frame_seal(frame_id: str, sealed_frame: str) -> bytes | None:
    """The seal a frame_id carries after ``sealed_frame`` (``generator|hmac-sha256|``), None if it carries none."""
    return frame_id[len(sealed_frame):].encode() if frame_id.startswith(sealed_frame) else None


def sealed_fields(topic: str, data: bytes) -> tuple[bytes | None, int, tuple] | None:
    """``(seal or None, stamp_ns, values)`` of a sealed contract ``topic``'s JointState bytes (:data:`SEALS`), where
    ``values`` are its positions, velocities and efforts in that order (what a seal covers,
    :func:`.command_auth.seal_mac`); None for bytes that are no JointState. For a recorder, which checks every
    sealed topic: the loop's sealed layout read in place, any other bytes deserialised."""
    fast = _sealed_layout(topic).unpack(data)
    if fast is not None:
        return fast[1][-1], fast[0], fast[1][:-1]
    try:
        msg = _deserialised(data, JointState)
    except ContractError:
        return None
    frame = msg.header.frame_id
    head, bar, _ = frame.partition("|")
    seal = frame_seal(frame, f"{head}|{command_auth.SCHEME}|") if bar else None
    return seal, ns_from_time(msg.header.stamp), (*msg.position, *msg.velocity, *msg.effort)


class SealCheck:
    """A recorder's check of one contract topic (``name``, at its absolute ``topic``) under the run's ``key``:
    :meth:`loops` is True for a message sealed by this run's node, in sequence, False for anything else. Topics
    without a seal (:data:`SEALS`), and every topic without a key, pass as they come.
    What the MCAP logger and the Foxglove bridge use to keep a rogue's messages apart from the loop's."""

    def __init__(self, key: bytes | None, topic: str, name: str):
        seal = SEALS.get(name) if key is not None else None
        self.name = name
        self._verifier = None if seal is None else command_auth.Verifier(
            key, topic, seal[0], seal[1] - command_auth.SEAL_LENGTH)

    def loops(self, data: bytes) -> bool:
        if self._verifier is None:
            return True
        fields = sealed_fields(self.name, data)
        return fields is not None and \
            self._verifier.check(fields[0], fields[1], *fields[2]) == command_auth.AUTHENTIC


_SEALED_LAYOUTS: dict = {}


def _sealed_layout(topic: str) -> cdr.StampedBytes:
    if topic not in _SEALED_LAYOUTS:
        _SEALED_LAYOUTS[topic] = layout(topic, sealed=True)
    return _SEALED_LAYOUTS[topic]


def command_from_bytes(data: bytes) -> tuple[int, float, bytes | None]:
    """``(answered stamp_ns, battery power pu, seal or None)`` of a command received as bytes; ContractError if
    malformed.

    As :func:`pmu_from_bytes`: the controller's layouts (:func:`command_bytes`, sealed or not) in place,
    else rclpy (:func:`command_from_message`, :func:`command_seal`).
    """
    fast = _SEALED_LAYOUT.unpack(data)
    if fast is not None:
        return fast[0], *fast[1]
    fast = _COMMAND_LAYOUT.unpack(data)
    if fast is not None:
        return fast[0], fast[1][0], None
    msg = _deserialised(data, JointState)
    return *command_from_message(msg), command_seal(msg)


def clock_from_bytes(data: bytes) -> int:
    """The time (ns) of a ``/clock`` message received as bytes; ContractError if malformed.

    As :func:`pmu_from_bytes`: the plant's layout in place, else rclpy. Every controller reads /clock at
    every lockstep sample (measured: a reader's CPU per message 27 us as bytes, 40 us deserialised).
    """
    fast = _CLOCK_LAYOUT.unpack(data)
    if fast is not None:
        return fast[0]
    return ns_from_time(_deserialised(data, Clock).clock)


def warm_up() -> None:
    """Build and read a measurement and a command, as messages and as bytes, publishing nothing.

    Profiled: a process's first JointState costs ~5 ms, which its first sample would otherwise
    pay as latency (the nodes read bytes, and deserialise what is not their peer's layout).
    """
    pmu_from_message(pmu_message(0, 0.0, 0.0, 0.0)), command_from_message(command_message(0, 0.0))
    pmu_from_bytes(_ROTOR_LAYOUT.pack(0, 0.0, 0.0, 0.0)), command_from_bytes(_COMMAND_LAYOUT.pack(0, 0.0))
    pmu_from_bytes(_SEALED_PMU_LAYOUT.pack(0, 0.0, 0.0, 0.0, b"0" * command_auth.MEASUREMENT_SEAL_LENGTH))
    command_from_bytes(_SEALED_LAYOUT.pack(0, 0.0, b"0" * command_auth.SEAL_LENGTH))
    clock_from_bytes(_CLOCK_LAYOUT.pack(0))


def plant_state_message(stamp_ns: int, delta_rad: float, speed_rad_s: float, battery_power_pu: float) -> JointState:
    """True rotor state; effort is the battery power acting on the rotor (pu)."""
    return pmu_message(stamp_ns, delta_rad, speed_rad_s, battery_power_pu)


def plant_state_from_message(msg: JointState) -> tuple[int, float, float, float]:
    """``(stamp_ns, delta rad, speed rad/s, battery power pu)``."""
    _expect_joint(msg, ROTOR_JOINT)
    if not all(math.isfinite(v) for v in (*msg.position, *msg.velocity)):
        raise ContractError(f"non-finite value in {ROTOR_JOINT!r} state")
    if len(msg.effort) != 1:
        raise ContractError("plant state must carry one effort (battery power)")
    return ns_from_time(msg.header.stamp), msg.position[0], msg.velocity[0], msg.effort[0]


def controller_state_message(stamp_ns: int, angle_dev_rad: float, x3: float, w: float, battery_power_pu: float,
                             saturated: bool, w_hat: float, battery_limit_pu: float) -> JointState:
    """The controller's internal signals, named in ``name``, values in ``position``."""
    msg = JointState()
    msg.header.stamp = time_from_ns(stamp_ns)
    msg.header.frame_id = CONTROLLER_FRAME
    msg.name = list(CONTROLLER_SIGNALS)
    msg.position = [float(angle_dev_rad), float(x3), float(w), float(battery_power_pu),
                    1.0 if saturated else 0.0, float(w_hat), float(battery_limit_pu)]
    return msg


def controller_state_bytes(seal_length: int = 0) -> cdr.StampedBytes:
    """The bytes of :func:`controller_state_message`: ``pack`` takes its arguments (``saturated`` a bool or 0/1),
    with a seal of ``seal_length`` bytes (0: none) the last."""
    if seal_length:
        return cdr.joint_state(SEALED_CONTROLLER_FRAME, CONTROLLER_SIGNALS, (len(CONTROLLER_SIGNALS), 0, 0),
                               seal_length)
    return cdr.joint_state(CONTROLLER_FRAME, CONTROLLER_SIGNALS, (len(CONTROLLER_SIGNALS), 0, 0))


#: The per-sample topics' layouts (:func:`layout`).
_LAYOUTS = {TOPIC_PMU: rotor_bytes, TOPIC_C37118_PMU: rotor_bytes, TOPIC_PLANT_STATE: rotor_bytes,
            TOPIC_BATTERY_COMMAND: command_bytes, TOPIC_CONTROLLER_STATE: controller_state_bytes, TOPIC_CLOCK: cdr.clock}


def layout(topic: str, sealed: bool = False) -> cdr.StampedBytes:
    """The bytes of a per-sample topic's messages as the loop's nodes publish them, in a buffer of its own;
    ``sealed``: with the topic's seal (:data:`SEALS`) as the last value."""
    if sealed:
        return _LAYOUTS[topic](SEALS[topic][1]) if topic != TOPIC_BATTERY_COMMAND else command_bytes(sealed=True)
    return _LAYOUTS[topic]()


def controller_state_from_message(msg: JointState) -> tuple[int, dict]:
    """``(stamp_ns, {signal name: value})``."""
    if tuple(msg.name) != CONTROLLER_SIGNALS or len(msg.position) != len(CONTROLLER_SIGNALS):
        raise ContractError(f"controller state must carry signals {CONTROLLER_SIGNALS}")
    return ns_from_time(msg.header.stamp), dict(zip(CONTROLLER_SIGNALS, msg.position))


def invariant_set_message(stamp_ns: int, boundary) -> PolygonStamped:
    """Omega's boundary as a polygon: x = angle deviation (rad), y = speed (rad/s)."""
    msg = PolygonStamped()
    msg.header.stamp = time_from_ns(stamp_ns)
    msg.header.frame_id = "phase_plane"
    msg.polygon.points = [Point32(x=float(x), y=float(y), z=0.0) for x, y in boundary]
    return msg


def diagnostics_message(stamp_ns: int, name: str, level: str, message: str, values: dict,
                        hardware_id: str) -> DiagnosticArray:
    """One DiagnosticStatus in a DiagnosticArray for ``/diagnostics`` (:func:`diagnostics_array` of one, its
    arguments in the order of a status there)."""
    return diagnostics_array(stamp_ns, [(name, level, message, values, hardware_id)])


def diagnostics_array(stamp_ns: int, statuses) -> DiagnosticArray:
    """A DiagnosticArray for ``/diagnostics`` of ``statuses``, each ``(name, level, message, values, hardware_id)``
    (the order of :meth:`.loop_node.LoopNode.publish_status`); ``values`` become KeyValue strings.

    ``level`` names a DiagnosticStatus constant (``"OK"``, ``"WARN"``, ``"ERROR"``), as the
    rclpy-free cores give it.

    ``hardware_id`` is the reporting node's fully qualified name (``/gen1/plant``); its namespace
    prefixes the status name (``gen1/plant``), so that the statuses of several generators on the
    one absolute topic stay apart (:func:`split_status_name` reads it back).
    """
    msg = DiagnosticArray()
    msg.header.stamp = time_from_ns(stamp_ns)
    for name, level, message, values, hardware_id in statuses:
        namespace = hardware_id.rpartition("/")[0].strip("/")
        status = DiagnosticStatus(level=getattr(DiagnosticStatus, level), message=message, hardware_id=hardware_id,
                                  name=f"{namespace}/{name}" if namespace else name)
        status.values = [KeyValue(key=key, value=_format_value(value)) for key, value in values.items()]
        msg.status.append(status)
    return msg


def split_status_name(status_name: str) -> tuple[str, str]:
    """``(namespace, name)`` of a status from :func:`diagnostics_message`: ``gen1/plant`` -> ``("/gen1", "plant")``."""
    namespace, _, name = status_name.rpartition("/")
    return (f"/{namespace}" if namespace else ""), name


def diagnostic_values(msg: DiagnosticArray, name: str) -> dict | None:
    """The key/value strings of the status called ``name``, or None if absent."""
    for status in msg.status:
        if status.name == name:
            return {kv.key: kv.value for kv in status.values}
    return None


#: The plant's diagnostics key that says its run has ended normally ("True"; "False" before and during it).
RUN_ENDED = "run_ended"


#: The key of the plant's status that seals its ``run_ended`` under the run's key (:func:`plant_run_ended`).
STATUS_SEAL = "seal"


def status_topic(hardware_id: str) -> str:
    """The name a plant's status seals are made for: ``/diagnostics`` and its hardware_id (``/diagnostics/gen1/plant``)."""
    return TOPIC_DIAGNOSTICS + hardware_id


def plant_run_ended(data: bytes, namespace: str, verifier=None) -> tuple[bool, str | None]:
    """``(ended, verdict)``: whether the plant of ``namespace`` (``/`` or ``/gen1``, as Node.get_namespace) says in
    these ``/diagnostics`` bytes that its run has ended (bytes that are no DiagnosticArray say nothing), and,
    with ``verifier`` (a :class:`.command_auth.Verifier` of kind ``status`` on :func:`status_topic`), what its
    seal is (None when nothing claims an end): a claim that is not AUTHENTIC ends nothing.

    Anyone can publish on ``/diagnostics``. Without a verifier a false notice only spares the
    controller its stand-down for the silence that follows it directly (the next measurement
    cancels it); the battery still goes to zero through the plant's own command timeouts.

    Deserialised only when the bytes hold the status name and a ``run_ended`` key whose value is
    ``True`` (:func:`_holds_run_ended`): every controller hears every status of the loop (a
    network plant's in one array), and a composed process of 52 controllers spent 29 % of its
    time converting them to Python messages (py-spy, kundur_ring_52 in lockstep).
    """
    namespace = namespace.strip("/")
    name = f"{namespace}/plant" if namespace else "plant"
    if name.encode() not in data or not _holds_run_ended(data):
        return False, None
    try:
        msg = _deserialised(data, DiagnosticArray)
    except ContractError:
        return False, None
    status = next((status for status in msg.status if status.name == name), None)
    values = None if status is None else {kv.key: kv.value for kv in status.values}
    if values is None or values.get(RUN_ENDED) != "True":
        return False, None
    if verifier is None:
        return True, None
    seal = values.get(STATUS_SEAL)
    verdict = verifier.check(None if seal is None else seal.encode(), ns_from_time(msg.header.stamp), 1.0)
    return verdict == command_auth.AUTHENTIC, verdict


#: A KeyValue's key ``run_ended`` in CDR: the string's bytes and its NUL (its length word precedes them).
_RUN_ENDED_KEY = RUN_ENDED.encode() + b"\x00"
#: Its value ``True`` in CDR, little and big endian: the length word (5, with the NUL), the bytes, the NUL.
_TRUE_VALUE = {b"\x00\x01": (5).to_bytes(4, "little") + b"True\x00", b"\x00\x00": (5).to_bytes(4, "big") + b"True\x00"}


def _holds_run_ended(data: bytes) -> bool:
    """Whether CDR bytes hold a ``run_ended`` key followed by the value ``True`` (a string aligned to 4 bytes
    from the payload's start, after the 4-byte encapsulation header): a necessary condition, read in place."""
    value = _TRUE_VALUE.get(data[:2])
    start = data.find(_RUN_ENDED_KEY) if value is not None else -1
    while start >= 0:
        end = start + len(_RUN_ENDED_KEY)
        at = end + (-(end - 4)) % 4
        if data[at:at + len(value)] == value:
            return True
        start = data.find(_RUN_ENDED_KEY, end)
    return False


def _format_value(value) -> str:
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _expect_joint(msg: JointState, joint: str) -> None:
    if list(msg.name) != [joint] or len(msg.position) != 1 or len(msg.velocity) != 1:
        raise ContractError(f"expected one joint {joint!r} with position and velocity, got names {list(msg.name)}")
