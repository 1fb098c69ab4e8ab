"""The PDC client core (nni_msgs_adapter.c37118.client): the session fed byte by byte, every rejection counted;
the client thread's reconnection to a PMU server that goes away and comes back.

The session tests are pure (bytes in, samples and commands out); the last
test uses loopback sockets. No ROS.
"""

from __future__ import annotations

import dataclasses
import socket
import time

import pytest

from c37118_cases import EPOCH_NS, bad_input_stream, data_frame, plant_config, plant_values
from nni_msgs_adapter.c37118 import frames as c37
from nni_msgs_adapter.c37118.client import PdcClient, PdcSession
from nni_msgs_adapter.c37118.server import PmuServer

CONFIG = plant_config(2)
CFG2 = c37.encode_config(CONFIG, c37.FrameType.CFG2, EPOCH_NS)


def data(k: int, *, stat=0) -> bytes:
    return data_frame(CONFIG, EPOCH_NS, k, stat=stat)


def commands(replies) -> list[int]:
    return [c37.decode_command(reply, idcode=7).command for reply in replies]


def configured(**options) -> PdcSession:
    session = PdcSession(7, **options)
    assert commands([session.opening()]) == [c37.Command.SEND_CFG2]
    samples, replies = session.feed(CFG2)
    assert samples == [] and commands(replies) == [c37.Command.DATA_ON]
    return session


def test_the_session_asks_for_cfg2_then_data_and_gives_samples_stamped_from_soc_fracsec():
    session = configured()
    samples, replies = session.feed(data(0) + data(1)[:50])
    assert replies == [] and [s.station for s in samples] == [0, 1]
    samples, _ = session.feed(data(1)[50:])
    (first, second) = samples
    values = plant_values(2, 1)
    assert first.instant_ns == EPOCH_NS + 20_000_000 and first.name == "G1 bus 31" and second.idcode == 102
    assert first.reading.angles_rad[0] == pytest.approx(float(values.angle_rad[0, 0]), abs=1e-6)
    assert first.reading.frequency_hz == pytest.approx(float(values.frequency_hz[0]), abs=1e-5)
    assert session.counters() == {"samples": 4, "frames": {"cfg2": 1, "data": 2}, "rejected": {}}


def test_every_bad_input_is_rejected_and_counted():
    session = configured()
    stream = bad_input_stream(CONFIG, EPOCH_NS)
    samples, replies = session.feed(stream)
    assert [s.instant_ns for s in samples[::2]] == [EPOCH_NS + k * 20_000_000 for k in (0, 2, 3, 6, 7, 8)]
    assert len(samples) == 11 and replies == []
    assert session.counters()["rejected"] == {"bad_crc": 1, "bad_sync": 1, "wrong_idcode": 1, "bad_framesize": 1,
                                              "truncated": 1, "invalid_data": 1, "time_backwards": 1,
                                              "duplicate": 1, "wrong_type": 1}


def test_data_before_any_configuration_and_stale_data_are_rejected():
    clock = [EPOCH_NS]
    session = PdcSession(7, max_age_ns=100_000_000, clock_ns=lambda: clock[0])
    session.opening()
    assert session.feed(data(0)) == ([], [])
    session.feed(CFG2)
    clock[0] = EPOCH_NS + 20_000_000 + 100_000_001
    assert session.feed(data(1))[0] == []
    clock[0] = EPOCH_NS + 2 * 20_000_000 + 100_000_000
    assert len(session.feed(data(2))[0]) == 2
    assert session.counters()["rejected"] == {"no_config": 1, "stale": 1}


def test_a_configuration_change_is_followed_by_one_new_cfg2_request():
    session = configured()
    changed = c37.Stat(config_changed=True).word
    _, replies = session.feed(data(1, stat=changed) + data(2, stat=changed))
    assert commands(replies) == [c37.Command.SEND_CFG2]
    _, replies = session.feed(CFG2 + data(3, stat=changed))
    assert commands(replies) == [c37.Command.SEND_CFG2]


def test_a_new_connection_starts_afresh():
    session = configured()
    session.feed(data(5) + data(6)[:20])
    session.closed()
    assert session.counters()["rejected"] == {"truncated": 1}
    session.opening()
    _, replies = session.feed(CFG2 + data(1))
    assert commands(replies) == [c37.Command.DATA_ON]
    assert session.counters()["samples"] == 4


def test_a_configuration_unlike_the_first_is_refused_and_ends_the_connection():
    session = configured()
    renamed = c37.Config(CONFIG.idcode, (dataclasses.replace(CONFIG.stations[0], name="rogue"), CONFIG.stations[1]),
                         CONFIG.data_rate)
    samples, replies = session.feed(data(1) + c37.encode_config(renamed, c37.FrameType.CFG2, EPOCH_NS) + data(2))
    assert len(samples) == 2 and replies == [], "the frame before it is read, none after it"
    assert session.refused.startswith("a configuration unlike the one this client took first")
    assert session.config == CONFIG and session.counters()["rejected"] == {"config_changed": 1}
    session.opening()  # a new connection: the same first configuration is taken again, the other is not
    assert commands(session.feed(CFG2)[1]) == [c37.Command.DATA_ON] and session.refused is None


def test_a_configuration_the_node_refuses_turns_no_data_on():
    session = PdcSession(7, accept_config=lambda config: f"{len(config.stations)} stations, not 3")
    session.opening()
    assert session.feed(CFG2 + data(0)) == ([], [])
    assert session.refused == "2 stations, not 3" and session.config is None
    assert session.counters()["rejected"] == {"config_mismatch": 1}


def test_the_client_drops_a_pmu_whose_configuration_it_refuses_and_says_why():
    port = _free_port()
    client = PdcClient("127.0.0.1", port, 7, lambda samples: None, accept_config=lambda config: "not ours",
                       retry_initial_s=0.05, retry_max_s=0.05)
    with PmuServer(CONFIG, "plant", port=port):
        client.start()
        try:
            deadline = time.monotonic() + 10
            while client.connections < 2:  # refused, dropped and tried again
                assert time.monotonic() < deadline
                time.sleep(0.01)
        finally:
            client.stop()
    assert f"PMU 127.0.0.1:{port} went away (its configuration is refused: not ours); reconnecting in 0.05 s" \
        in client.events()
    assert client.counters()["rejected"]["config_mismatch"] >= 1 and client.counters()["samples"] == 0


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_the_client_reconnects_when_the_pmu_comes_back():
    port = _free_port()
    samples = []
    client = PdcClient("127.0.0.1", port, 7, samples.extend, retry_initial_s=0.05, retry_max_s=0.2)
    client.start()
    try:
        for round_ in range(2):
            deadline = time.monotonic() + 10
            while client.connect_failures <= round_:  # the PMU is away: refused, and retried
                assert time.monotonic() < deadline
                time.sleep(0.01)
            with PmuServer(CONFIG, "plant", port=port) as server:
                while server.counters()["commands"].get("data_on") != 1:
                    assert time.monotonic() < deadline
                    time.sleep(0.01)
                before = len(samples)
                server.offer(EPOCH_NS + round_ * 10**9, plant_values(2, 0))
                while len(samples) < before + 2:
                    assert time.monotonic() < deadline
                    time.sleep(0.01)
            while client.connected:
                time.sleep(0.01)
    finally:
        client.stop()
    counters = client.counters()
    assert counters["connections"] == 2 and counters["connect_failures"] >= 2 and counters["rejected"] == {}
    lines = client.events()
    assert lines[0] == f"PMU 127.0.0.1:{port} unreachable (Connection refused); retrying in 0.05 s"
    assert f"connected to PMU 127.0.0.1:{port}" in lines
    assert any(line.startswith(f"PMU 127.0.0.1:{port} went away (closed by the PMU)") for line in lines)
