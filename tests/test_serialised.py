"""The loop's per-sample messages as bytes: exactly rclpy's serialisation of the message the contract builds.

The plant and the controller publish what :class:`Serialiser` returns; a
subscriber, the logger and every recording see those bytes. They must equal
``serialize_message`` of the contract's message for any values, including the
ones a run produces at its edges (NaN W_hat of a generator in a network, an
infinite battery limit, negative zero, a stamp before the epoch's second).
"""

from __future__ import annotations

import math
import random

import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.serialised import Serialiser

BUILDERS = [(contract.pmu_message, 3), (contract.plant_state_message, 3), (contract.command_message, 1),
            (contract.controller_state_message, 7), (contract.clock_message, 0)]
EDGE_VALUES = [0.0, -0.0, math.nan, math.inf, -math.inf, 1e-310, -1.7976931348623157e308, 0.3]


@pytest.mark.parametrize("build, count", BUILDERS, ids=[build.__name__ for build, _ in BUILDERS])
def test_every_per_sample_message_is_patched_and_equals_rclpys_bytes(build, count):
    serialiser = Serialiser(build, count)
    assert serialiser.patched  # else the nodes would pay rclpy's serialisation at every sample
    rng = random.Random(7)
    stamps = [0, 1, 999_999_999, 1_000_000_000, 1_764_597_600_123_456_789, 2**31 * 1_000_000_000 - 1]
    for k in range(200):
        stamp = stamps[k] if k < len(stamps) else rng.randrange(0, 2**31 * 1_000_000_000)
        values = [rng.choice(EDGE_VALUES) if rng.random() < 0.3 else rng.uniform(-10, 10) for _ in range(count)]
        assert serialiser.serialise(stamp, *values) == serialize_message(build(stamp, *values)), (stamp, values)


def test_the_controller_states_saturated_flag_goes_out_as_one_or_zero():
    serialiser = Serialiser(contract.controller_state_message, 7)
    for saturated in (True, False):
        data = serialiser.serialise(5, 0.1, 0.2, 0.3, 0.3, saturated, math.nan, math.inf)
        _, signals = contract.controller_state_from_message(deserialize_message(data, JointState))
        assert signals["saturated"] == (1.0 if saturated else 0.0) and math.isinf(signals["battery_limit"])


def test_the_bytes_read_back_as_the_values_and_stamp_given():
    data = Serialiser(contract.pmu_message, 3).serialise(12_345_678_901, 0.75, -0.5, 1.25)
    assert contract.pmu_from_message(deserialize_message(data, JointState)) == (12_345_678_901, 0.75, -0.5)
    clock = deserialize_message(Serialiser(contract.clock_message, 0).serialise(3_000_000_007), Clock)
    assert contract.ns_from_time(clock.clock) == 3_000_000_007


def test_a_layout_that_depends_on_the_values_is_serialised_by_rclpy_instead():
    """A message whose length changes with a value's sign is caught by the check: every call then serialises it."""
    def build(stamp_ns, power):
        msg = contract.command_message(stamp_ns, power)
        msg.header.frame_id = "battery" if power < 0 else "battery, charging"
        return msg

    serialiser = Serialiser(build, 1)
    assert not serialiser.patched
    for power in (0.5, 1.5, 2.5, math.nan):
        assert serialiser.serialise(9, power) == serialize_message(build(9, power))


def test_a_wrong_number_of_values_is_refused():
    serialiser = Serialiser(contract.command_message, 1)
    with pytest.raises(TypeError, match="1 values expected, got 2"):
        serialiser.serialise(1, 0.1, 0.2)
