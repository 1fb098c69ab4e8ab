"""The client node's core (nni_msgs_adapter.c37118.feed): station samples to the controllers' measurements.

Pure: a PdcSession fed frames, its samples through StationFeeds. No ROS.
"""

from __future__ import annotations

import math

import numpy as np

from c37118_cases import data_frame, plant_config
from nni_msgs_adapter.c37118 import frames as c37
from nni_msgs_adapter.c37118 import profile
from nni_msgs_adapter.c37118.client import PdcSession
from nni_msgs_adapter.c37118.feed import StationFeeds, unwrapped

LOCKSTEP_T0_NS = profile.LOCKSTEP_EPOCH_NS
CONFIG = profile.stream_config(1, ("gen1 G1 bus 1", "gen2 G2 bus 2"), 50, 50, True, "float")


def frame(k: int, angle_rad, *, config=CONFIG, frequency_hz=50.01) -> bytes:
    n = len(config.stations)
    values = c37.Measurements(np.zeros(n, dtype=int), np.ones((n, 3)), np.column_stack([angle_rad, np.zeros((n, 2))]),
                              np.full(n, frequency_hz), np.zeros(n), np.column_stack([np.full(n, 0.7), np.zeros(n)]))
    return c37.DataFrameEncoder(config).encode(LOCKSTEP_T0_NS + k * 20_000_000, values)


def session_samples(*frames: bytes, config=CONFIG):
    session = PdcSession(config.idcode)
    session.opening()
    session.feed(c37.encode_config(config, c37.FrameType.CFG2, LOCKSTEP_T0_NS))
    return session, [session.feed(f)[0] for f in frames]


def test_a_lockstep_stream_gives_the_plants_stamps_angles_speed_and_power():
    session, (samples,) = session_samples(frame(3, [0.25, -1.0]))
    feeds = StationFeeds(2, lockstep=True)
    (first, second) = feeds.take(samples, session.config, 1)
    assert first.index == 0 and second.index == 1
    assert first.stamp_ns == second.stamp_ns == 60_000_000, "the epoch taken off: simulated ns"
    assert first.angle_rad == float(np.float32(0.25)) and second.angle_rad == float(np.float32(-1.0))
    assert math.isclose(first.speed_rad_s, 2 * math.pi * (float(np.float32(50.01)) - 50.0), rel_tol=1e-12)
    assert first.power_pu == float(np.float32(0.7))


def test_the_angle_turns_on_across_pi_and_starts_afresh_on_a_new_connection():
    angles = [3.0, -3.0, -2.5]  # on the wire: a rotor turning on past pi
    session, frames = session_samples(*(frame(k, [a, 0.0]) for k, a in enumerate(angles)))
    feeds = StationFeeds(2, lockstep=True, plausible_step_rad=math.pi)  # these steps are not the frequency's
    taken = [feeds.take(samples, session.config, 1)[0].angle_rad for samples in frames]
    assert np.allclose(taken, [3.0, 2 * math.pi - 3.0, 2 * math.pi - 2.5], atol=1e-6)
    assert feeds.take(frames[2], session.config, 2)[0].angle_rad == float(np.float32(-2.5))
    assert unwrapped(None, 1.0) == 1.0 and math.isclose(unwrapped(6.0, -0.2), 2 * math.pi - 0.2)


def test_stations_beyond_the_namespaces_and_without_the_named_channels_are_counted():
    session, (samples,) = session_samples(frame(0, [0.1, 0.2]))
    assert [m.index for m in StationFeeds(1, lockstep=True).take(samples, session.config, 1)] == [0]
    unmapped = StationFeeds(1, lockstep=True)
    unmapped.take(samples, session.config, 1)
    assert unmapped.rejected == {"unmapped_station": 1}
    missing = StationFeeds(2, lockstep=True, angle_phasor="no such phasor")
    assert missing.take(samples, session.config, 1) == [] and missing.rejected == {"missing_channel": 2}
    no_power = StationFeeds(2, lockstep=True, power_analog="")
    assert all(math.isnan(m.power_pu) for m in no_power.take(samples, session.config, 1))


def test_the_status_is_error_unconnected_warn_while_rejections_grow_else_ok():
    config = plant_config(2)
    session, (samples,) = session_samples(data_frame(config, LOCKSTEP_T0_NS, 0), config=config)
    feeds = StationFeeds(1, lockstep=True, angle_phasor="EMF E'", power_analog="")
    feeds.take(samples, session.config, 1)
    counters = {"connected": True, "connections": 1, "connect_failures": 0, **session.counters()}
    level, message, values = feeds.status(counters)
    assert (level, message) == ("WARN", "rejected: unmapped_station")
    assert values["rejected_unmapped_station"] == 1 and values["published"] == 1 and values["frames_data"] == 1
    assert feeds.status(counters)[:2] == ("OK", "receiving")
    assert feeds.status({**counters, "connected": False})[:2] == ("ERROR", "not connected to the PMU")


def test_an_angle_step_its_frequency_does_not_explain_is_rejected_and_not_taken_as_the_reference():
    # 1 Hz above nominal: the angle advances 2 pi x 1 Hz x 20 ms = 0.12566 rad a frame.
    step = 2 * math.pi * 1.0 * 0.02
    angles = [0.1 + k * step for k in range(6)]
    wire = list(angles)
    wire[3] += 0.5  # a man in the middle moves one angle, not its frequency
    session, frames = session_samples(*(frame(k, [a, a], frequency_hz=51.0) for k, a in enumerate(wire)))
    feeds = StationFeeds(2, lockstep=True)
    taken = [[m.angle_rad for m in feeds.take(samples, session.config, 1)] for samples in frames]
    assert [len(t) for t in taken] == [2, 2, 2, 0, 2, 2]
    assert np.allclose([t[0] for t in taken if t], [angles[k] for k in (0, 1, 2, 4, 5)], atol=1e-6)
    assert feeds.rejected == {"implausible": 2}
    counters = {"connected": True, "connections": 1, "connect_failures": 0, **session.counters()}
    level, message, values = feeds.status(counters)
    assert (level, values["rejected_implausible"]) == ("ERROR", 2)
    assert message == "rejected: implausible (an angle step its frequency does not explain, beyond 0.1 rad)"
    # A step within the bound passes: 0.09 rad beyond the frequency's.
    session, frames = session_samples(frame(0, [0.1, 0.1], frequency_hz=51.0),
                                      frame(1, [0.1 + step + 0.09] * 2, frequency_hz=51.0))
    lenient = StationFeeds(2, lockstep=True)
    assert [len(lenient.take(samples, session.config, 1)) for samples in frames] == [2, 2]


def test_a_configuration_without_the_node_s_stations_or_channels_is_named():
    config = plant_config(2)
    assert StationFeeds(2, lockstep=True, angle_phasor="EMF E'", power_analog="").config_fault(config) is None
    assert StationFeeds(1, lockstep=True, angle_phasor="EMF E'", power_analog="").config_fault(config) is None
    assert StationFeeds(3, lockstep=True, angle_phasor="EMF E'", power_analog="").config_fault(config) == \
        "the stream has 2 station(s), this node maps 3 namespace(s)"
    assert StationFeeds(2, lockstep=True, angle_phasor="rotor", power_analog="").config_fault(config) == \
        "station 'G1 bus 31' has no phasor 'rotor'"
    assert StationFeeds(2, lockstep=True, angle_phasor="", power_analog="P_E pu").config_fault(config) == \
        "station 'G1 bus 31' has no analog 'P_E pu'"
    status = StationFeeds(2, lockstep=True).status(
        {"connected": True, "connections": 1, "connect_failures": 0, "samples": 0, "frames": {"cfg2": 1},
         "rejected": {"config_mismatch": 1}})
    assert status[:2] == ("ERROR", "rejected: config_mismatch (a configuration this node does not take)")
