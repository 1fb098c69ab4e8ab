"""The loop's per-sample messages as bytes (nni_msgs_adapter.ros.cdr) are what a normal publish puts on the wire.

The oracle is Fast DDS itself: each message is published once by rclpy as a
message and once as our bytes, on real DDS in this process, and a raw
subscription receives both. They must be equal byte for byte (padding
included: a recording of either is the same file), for the contract's layouts
and for odd ones (empty strings and sequences, lengths off the alignments),
with edge values.
"""

from __future__ import annotations

import math
import time

import pytest
from rosgraph_msgs.msg import Clock

from nni_msgs_adapter.ros import cdr, contract
from rosproc import fresh_domain_id

STAMPS_NS = (0, 1_764_597_600_123_456_789, 2_147_483_647_999_999_999, -1)
VALUES = (0.25, -3.5, math.nan, math.inf, -math.inf, -0.0, 1e300, 5e-324, 1.0, 7.0)

LAYOUTS = [  # (frame_id, names, (position, velocity, effort) counts)
    ("generator", (contract.ROTOR_JOINT,), (1, 1, 1)),  # pmu and plant/state
    ("battery", (contract.BATTERY_JOINT,), (0, 0, 1)),  # battery/command
    ("controller", contract.CONTROLLER_SIGNALS, (7, 0, 0)),  # controller/state
    ("", (), (0, 0, 0)),
    ("ab", ("x", "yyyy", "zzzzzzz", ""), (2, 3, 0)),
    ("a" * 9, ("q",), (0, 1, 2)),
    ("abc", ("rotor", "battery"), (3, 0, 0)),
]


@pytest.fixture(scope="module")
def wire():
    """``send(msg_class, msg, data) -> (bytes of msg, bytes of data)`` as a raw reader received them."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    node = rclpy.create_node("cdr_oracle", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    topics = iter(range(1000))

    def send(msg_class, msg, data):
        name, received = f"/cdr_test_{next(topics)}", []
        qos = contract.SAMPLE_QOS
        subscription = node.create_subscription(msg_class, name, received.append, qos, raw=True)
        publisher = node.create_publisher(msg_class, name, qos)
        deadline = time.monotonic() + 10.0
        while publisher.get_subscription_count() < 1 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.01)
        publisher.publish(msg)
        publisher.publish(data)
        while len(received) < 2 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.01)
        node.destroy_publisher(publisher)
        node.destroy_subscription(subscription)
        assert len(received) == 2, f"{name}: {len(received)} of 2 messages arrived within 10 s"
        return received[0], received[1]

    yield send
    executor.shutdown(timeout_sec=1.0)
    node.destroy_node()
    rclpy.try_shutdown(context=context)


@pytest.mark.parametrize("frame_id, names, counts", LAYOUTS)
def test_a_joint_states_bytes_are_what_a_normal_publish_sends(wire, frame_id, names, counts):
    from sensor_msgs.msg import JointState

    layout = cdr.joint_state(frame_id, names, counts)
    assert layout.count == sum(counts)
    for index, stamp_ns in enumerate(STAMPS_NS):
        values = [VALUES[(index + k) % len(VALUES)] for k in range(sum(counts))]
        position, velocity, effort = values[:counts[0]], values[counts[0]:sum(counts[:2])], values[sum(counts[:2]):]
        msg = JointState(name=list(names), position=position, velocity=velocity, effort=effort)
        msg.header.stamp, msg.header.frame_id = contract.time_from_ns(stamp_ns), frame_id
        normal, ours = wire(JointState, msg, layout.pack(stamp_ns, *values))
        assert ours == normal


def test_a_clocks_bytes_are_what_a_normal_publish_sends(wire):
    layout = cdr.clock()
    for stamp_ns in STAMPS_NS:
        normal, ours = wire(Clock, Clock(clock=contract.time_from_ns(stamp_ns)), layout.pack(stamp_ns))
        assert ours == normal


CONTRACT = [  # (the message builder, the topic whose nodes publish bytes instead, arguments after the stamp)
    (contract.pmu_message, contract.TOPIC_PMU, (0.2, -1.5, 0.75)),
    (contract.plant_state_message, contract.TOPIC_PLANT_STATE, (math.nan, math.inf, -0.0)),
    (contract.command_message, contract.TOPIC_BATTERY_COMMAND, (0.3,)),
    (contract.controller_state_message, contract.TOPIC_CONTROLLER_STATE, (0.1, -0.2, 0.3, 0.3, True, 0.05, math.inf)),
    (contract.controller_state_message, contract.TOPIC_CONTROLLER_STATE, (0.1, -0.2, 0.3, 0.3, False, math.nan, 1.0)),
    (lambda stamp_ns: Clock(clock=contract.time_from_ns(stamp_ns)), contract.TOPIC_CLOCK, ()),
]


@pytest.mark.parametrize("build, topic, values", CONTRACT)
def test_the_contracts_bytes_are_its_messages(wire, build, topic, values):
    """What the plant and the controller publish as bytes (the topic's layout) is the contract's message, on the wire."""
    for stamp_ns in STAMPS_NS[:3]:
        msg = build(stamp_ns, *values)
        normal, ours = wire(type(msg), msg, contract.layout(topic).pack(stamp_ns, *values))
        assert ours == normal


def test_a_sealed_commands_bytes_are_its_message_on_the_wire(wire):
    """The sealed command's layout (the seal a fixed-length text slot at the frame_id's end) is command_message's."""
    for stamp_ns in STAMPS_NS[:3]:
        seal = b"%016x|" % stamp_ns + b"0123456789abcdef" * 4
        msg = contract.command_message(stamp_ns, 0.25, seal)
        normal, ours = wire(type(msg), msg, contract.command_bytes(sealed=True).pack(stamp_ns, 0.25, seal))
        assert ours == normal
    with pytest.raises(ValueError, match="text slot takes 81 bytes, got 3"):
        contract.command_bytes(sealed=True).pack(0, 0.25, b"abc")


def test_a_wrong_number_of_values_is_refused():
    with pytest.raises(TypeError, match="3 values expected, got 2"):
        cdr.joint_state("generator", ("rotor",), (1, 1, 1)).pack(0, 1.0, 2.0)


def test_the_peers_bytes_read_back_in_place_and_any_other_message_through_rclpy():
    """pmu_from_bytes / command_from_bytes: the peer's layout read in place, other valid messages as rclpy reads them."""
    from rclpy.serialization import serialize_message

    pmu = contract.rotor_bytes().pack(7_000_000_001, 0.2, -1.5, 0.75)
    assert contract.pmu_from_bytes(pmu) == ((7_000_000_001, 0.2, -1.5), (0.75,), None)
    measurement_seal = b"L|" + b"%016x|" % 7 + b"cd" * 32
    sealed_pmu = contract.rotor_bytes(len(measurement_seal)).pack(7_000_000_001, 0.2, -1.5, 0.75, measurement_seal)
    assert contract.pmu_from_bytes(sealed_pmu) == ((7_000_000_001, 0.2, -1.5), (0.75,), measurement_seal)
    assert contract.pmu_from_bytes(serialize_message(contract.pmu_message(3, 0.1, 0.2, 0.3, measurement_seal))) == \
        ((3, 0.1, 0.2), (0.3,), measurement_seal)
    assert contract.sealed_fields(contract.TOPIC_PMU, sealed_pmu) == (measurement_seal, 7_000_000_001, (0.2, -1.5, 0.75))
    assert contract.sealed_fields(contract.TOPIC_PMU, serialize_message(contract.pmu_message(3, 0.1, 0.2, 0.3))) == \
        (None, 3, (0.1, 0.2, 0.3))
    assert contract.command_from_bytes(contract.command_bytes().pack(7_000_000_001, -0.3)) == (7_000_000_001, -0.3,
                                                                                                None)
    seal = b"%016x|" % 7 + b"ab" * 32
    sealed = contract.command_bytes(sealed=True).pack(7_000_000_001, -0.3, seal)
    assert contract.command_from_bytes(sealed) == (7_000_000_001, -0.3, seal)
    # Not the peer's layout but valid: another frame_id, rclpy's own (over-long) serialisation, more efforts.
    other = cdr.joint_state("elsewhere", (contract.BATTERY_JOINT,), (0, 0, 1)).pack(5, 0.25)
    assert contract.command_from_bytes(other) == (5, 0.25, None)
    assert contract.command_from_bytes(serialize_message(contract.command_message(9, 0.5))) == (9, 0.5, None)
    assert contract.command_from_bytes(serialize_message(contract.command_message(9, 0.5, seal))) == (9, 0.5, seal)
    two = cdr.joint_state("generator", (contract.ROTOR_JOINT,), (1, 1, 2)).pack(3, 0.1, 0.2, 0.3, 0.4)
    assert contract.pmu_from_bytes(two) == ((3, 0.1, 0.2), (0.3, 0.4), None)
    assert contract.clock_from_bytes(cdr.clock().pack(7_000_000_001)) == 7_000_000_001
    assert contract.clock_from_bytes(serialize_message(Clock(clock=contract.time_from_ns(9)))) == 9


@pytest.mark.parametrize("data", [
    b"", b"\x00\x01\x00\x00", contract.command_bytes().pack(1, 0.5)[:-3], bytes(range(60)),
    contract.rotor_bytes().pack(1, 0.1, 0.2, 0.3),  # a measurement on the command topic
    cdr.joint_state("battery", ("battery",), (0, 0, 2)).pack(1, 0.5, 0.5),  # two efforts
])
def test_bytes_that_are_no_command_are_a_contract_error(data):
    with pytest.raises(contract.ContractError):
        contract.command_from_bytes(data)


@pytest.mark.parametrize("data", [
    b"", contract.rotor_bytes().pack(1, 0.1, 0.2, 0.3)[:40],
    contract.command_bytes().pack(1, 0.5),  # a command on the measurement topic
])
def test_bytes_that_are_no_measurement_are_a_contract_error(data):
    with pytest.raises(contract.ContractError):
        contract.pmu_from_bytes(data)


@pytest.mark.parametrize("data", [b"", b"\x00\x01\x00\x00", cdr.clock().pack(1)[:-2]])
def test_bytes_that_are_no_clock_are_a_contract_error(data):
    with pytest.raises(contract.ContractError):
        contract.clock_from_bytes(data)


def test_the_plants_end_of_run_is_read_from_diagnostics_bytes_of_its_own_namespace_only():
    """plant_run_ended reads /diagnostics bytes: the plant of the controller's namespace says run_ended True there.

    Not another generator's plant (gen11 beside gen1), not a status without it or saying False, not bytes that are
    no DiagnosticArray; the root namespace's plant is ``plant``.
    """
    from rclpy.serialization import serialize_message

    def status(hardware_id: str, name: str, ended) -> bytes:
        values = {"samples": 500, contract.RUN_ENDED: ended} if ended is not None else {"samples": 500}
        return serialize_message(contract.diagnostics_message(1, name, "OK", "running", values, hardware_id))

    ended = status("/gen1/plant", "plant", True)
    assert contract.plant_run_ended(ended, "/gen1")[0]
    assert not contract.plant_run_ended(ended, "/gen11")[0] and not contract.plant_run_ended(ended, "/")[0]
    assert not contract.plant_run_ended(status("/gen11/plant", "plant", True), "/gen1")[0]
    assert not contract.plant_run_ended(status("/gen1/plant", "plant", False), "/gen1")[0]
    assert not contract.plant_run_ended(status("/gen1/controller", "controller", None), "/gen1")[0]
    assert contract.plant_run_ended(status("/plant", "plant", True), "/")[0]
    assert not contract.plant_run_ended(b"gen1/plant True" + bytes(40), "/gen1")[0]


def test_a_network_plants_statuses_in_one_array_say_which_generators_run_ended(monkeypatch):
    """The network plant sends every generator's status in one DiagnosticArray: the end of the run is read for the
    controller's own generator only, and a ``True`` of another key (or of another generator) is not its end. Bytes
    where no run_ended is True are not deserialised (every controller reads every array, every second)."""
    from rclpy.serialization import serialize_message

    deserialised = []
    real = contract._deserialised
    monkeypatch.setattr(contract, "_deserialised", lambda *args: deserialised.append(1) or real(*args))

    def array(ended: dict) -> bytes:
        statuses = [("plant", "OK", "running",
                     {"samples": 500, "paired": True, contract.RUN_ENDED: ended.get(i, False), "x": "True"},
                     f"/gen{i}/plant") for i in (1, 2, 11)]
        return serialize_message(contract.diagnostics_array(1, statuses))

    assert [contract.plant_run_ended(array({}), f"/gen{i}")[0] for i in (1, 2, 11)] == [False] * 3
    assert not deserialised
    assert [contract.plant_run_ended(array({11: True}), f"/gen{i}")[0] for i in (1, 2, 11)] == [False, False, True]
    assert [contract.plant_run_ended(array({1: True, 2: True, 11: True}), f"/gen{i}")[0] for i in (1, 2, 11)] == [True] * 3


def test_with_the_runs_key_only_the_plants_sealed_end_of_run_ends_it():
    """A run_ended True counts only with its plant's seal (kind status, under /diagnostics and its hardware_id):
    an unsealed claim, one sealed for another generator, or the plant's own sent again end nothing, and say why."""
    from rclpy.serialization import serialize_message

    from nni_msgs_adapter.ros import command_auth

    key = bytes(range(32))
    signer = command_auth.Signer(key, contract.status_topic("/gen1/plant"), "status")

    def status(stamp: int, seal: bytes | None, hardware_id: str = "/gen1/plant") -> bytes:
        values = {contract.RUN_ENDED: True, **({contract.STATUS_SEAL: seal.decode()} if seal else {})}
        return serialize_message(contract.diagnostics_message(stamp, "plant", "OK", "ended", values, hardware_id))

    def verifier():
        return command_auth.Verifier(key, contract.status_topic("/gen1/plant"), "status")

    gen1 = verifier()
    real = status(5, signer.seal(5, 1.0))
    assert contract.plant_run_ended(real, "/gen1", gen1) == (True, command_auth.AUTHENTIC)
    assert contract.plant_run_ended(real, "/gen1", gen1) == (False, command_auth.REPLAYED)
    assert contract.plant_run_ended(status(6, None), "/gen1", verifier()) == (False, command_auth.UNAUTHENTICATED)
    assert contract.plant_run_ended(status(7, signer.seal(8, 1.0)), "/gen1", verifier())[0] is False  # other stamp
    other = command_auth.Signer(key, contract.status_topic("/gen2/plant"), "status").seal(9, 1.0)
    assert contract.plant_run_ended(status(9, other), "/gen1", verifier()) == (False, command_auth.UNAUTHENTICATED)
    assert contract.plant_run_ended(real, "/gen1") == (True, None)  # without a key: as before
