"""The PMU server core (nni_msgs_adapter.c37118.server) on real loopback sockets: PDCs of two implementations,
bad commands, a PDC that never reads, connection churn.

pyc37's ``Pdc`` (an independent implementation) connects, gets CFG-2 and the
header, turns data on and reads frames; our own client core does the same.
No ROS.
"""

from __future__ import annotations

import os
import socket
import struct
import threading
import time

import numpy as np
import pytest
from numpy.testing import assert_array_equal
from pyc37.frame import DataFrame as PyData
from pyc37.pdc import Pdc

from c37118_cases import EPOCH_NS, PYC37_FORMAT, plant_config, plant_values, wrapped
from nni_msgs_adapter.c37118 import frames as c37
from nni_msgs_adapter.c37118.client import PdcClient
from nni_msgs_adapter.c37118.server import PmuServer

HEADER = "test plant: EMF, terminal voltage and current per generator"


def wait_for(condition, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        time.sleep(0.005)


def connect(server: PmuServer) -> socket.socket:
    return socket.create_connection(server.address, timeout=5)


def command(cmd: int, idcode: int = 7) -> bytes:
    return c37.encode_command(idcode, cmd, EPOCH_NS)


def read_frame(sock: socket.socket) -> bytes:
    head = b""
    while len(head) < 4:
        head += sock.recv(4 - len(head))
    size = struct.unpack(">H", head[2:4])[0]
    body = b""
    while len(head) + len(body) < size:
        body += sock.recv(size - len(head) - len(body))
    return head + body


@pytest.fixture
def server():
    with PmuServer(plant_config(3, data_format=PYC37_FORMAT), HEADER, port=0, queue_frames=50) as pmu:
        yield pmu


def test_pyc37s_pdc_gets_cfg2_and_header_turns_data_on_and_reads_the_frames(server):
    pdc = Pdc(pdc_id=7, pmu_ip=server.address[0], pmu_port=server.address[1])
    pdc.logger.setLevel("ERROR")
    pdc.run()
    cfg = pdc.get_config("cfg2")
    assert [name.rstrip() for name in cfg.get_station_name()] == ["G1 bus 31", "G2 bus 32", "G3 bus 33"]
    assert pdc.get_header().get_header() == repr(HEADER.encode())  # pyc37 returns the bytes' repr (its bug)
    pdc.start()
    wait_for(lambda: server.counters()["commands"].get("data_on") == 1)
    angles = []
    for k in range(40):
        values = plant_values(3, k)
        server.offer(EPOCH_NS + k * 20_000_000, values)
        frame = pdc.get()
        assert isinstance(frame, PyData)
        measured = frame.get_measurements()
        assert measured["time"] == pytest.approx((EPOCH_NS + k * 20_000_000) / 1e9, abs=1e-6)
        angles.append([station["phasors"][0][1] for station in measured["measurements"]])
        assert_array_equal(angles[-1], np.float32(wrapped(values.angle_rad[:, 0])))
    pdc.stop()
    pdc.quit()
    wait_for(lambda: server.counters()["connected"] == 0)
    counters = server.counters()
    assert counters["commands"] == {"send_cfg2": 1, "send_header": 1, "data_on": 1, "data_off": 1}
    assert counters["frames_sent"] == 42 and counters["frames_dropped"] == 0 and counters["rejected"] == {}
    lines = server.events()
    assert lines[0].startswith("PDC 127.0.0.1:") and lines[0].endswith("connected")
    assert "turned data on" in lines[1] and "went away (closed by the PDC): sent 42 frames, dropped 0" in lines[-1]
    departed, = counters["departed"]  # what it was sent and lost, kept once it went away
    assert (departed["frames_sent"], departed["frames_dropped"], departed["why"]) == (42, 0, "closed by the PDC")
    assert departed["address"] == lines[0].split()[1] and counters["pdcs"] == []


def test_our_client_core_gets_the_config_turns_data_on_and_reads_the_samples(server):
    samples, arrived = [], threading.Event()

    def take(batch):
        samples.extend(batch)
        if len(samples) >= 60:
            arrived.set()

    client = PdcClient(*server.address, 7, take)
    client.start()
    try:
        wait_for(lambda: server.counters()["commands"].get("data_on") == 1)
        for k in range(20):
            server.offer(EPOCH_NS + k * 20_000_000, plant_values(3, k))
        assert arrived.wait(5)
    finally:
        client.stop()
    assert len(samples) == 60 and client.counters()["rejected"] == {}
    last = samples[-1]
    assert (last.station, last.name, last.idcode) == (2, "G3 bus 33", 103)
    assert last.instant_ns == EPOCH_NS + 19 * 20_000_000
    assert last.reading.angles_rad[0] == pytest.approx(float(wrapped(plant_values(3, 19).angle_rad[2, 0])), abs=1e-6)


def test_bad_and_out_of_order_commands_are_counted_and_change_nothing(server):
    with connect(server) as sock:
        damaged = bytearray(command(c37.Command.DATA_ON))
        damaged[-1] ^= 1
        oversized = bytearray(command(c37.Command.DATA_ON))
        oversized[2:4] = (5000).to_bytes(2, "big")
        # Each bad stretch of the byte stream counts once: a good frame follows each here.
        for junk in (b"GET / HTTP/1.1\r\n\r\n", command(c37.Command.DATA_OFF), bytes(damaged),
                     command(c37.Command.EXTENDED), command(c37.Command.DATA_ON, idcode=8), command(7),
                     c37.encode_header(7, "not a command", EPOCH_NS), bytes(oversized)):
            sock.sendall(junk)
        sock.sendall(command(c37.Command.SEND_CFG1) + command(c37.Command.SEND_CFG3))
        assert c37.decode_config(read_frame(sock)).head.frame_type == c37.FrameType.CFG1
        assert c37.decode_config(read_frame(sock)).config == server.config
        (pdc,) = server.counters()["pdcs"]
        assert pdc["rejected"] == {"bad_sync": 1, "bad_crc": 1, "wrong_idcode": 1, "unknown_command": 1,
                                   "wrong_type": 1, "oversized": 1}
        assert pdc["redundant"] == 1 and not pdc["data_on"]
        assert pdc["commands"] == {"data_off": 1, "extended": 1, "send_cfg1": 1, "send_cfg3": 1}
        server.offer(EPOCH_NS, plant_values(3, 0))
        assert server.counters()["pdcs"][0]["frames_sent"] == 2


def test_a_pdc_that_never_reads_loses_frames_alone_and_never_slows_the_offers():
    """Beside a stalled PDC the offers take what they take beside a reading one only: each offer is timed against
    the same offer to a second server that has a reading PDC alone, alternately, so the machine's load cancels."""
    config = plant_config(52)
    with PmuServer(config, HEADER, port=0, queue_frames=50) as server, PmuServer(config, HEADER, port=0) as baseline:
        stalled = socket.socket()
        stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stalled.connect(server.address)
        stalled.sendall(command(c37.Command.DATA_ON))
        received, baseline_received = [], []
        reader = PdcClient(*server.address, 7, received.extend)
        baseline_reader = PdcClient(*baseline.address, 7, baseline_received.extend)
        reader.start()
        baseline_reader.start()
        wait_for(lambda: server.counters()["commands"].get("data_on") == 2
                 and baseline.counters()["commands"].get("data_on") == 1)
        values = plant_values(52, 0)
        offer_s, baseline_s, worst_queue = [], [], 0
        for k in range(1500):
            for target, times in ((server, offer_s), (baseline, baseline_s)):
                start = time.perf_counter()
                target.offer(EPOCH_NS + k * 1_000_000, values)
                times.append(time.perf_counter() - start)
            time.sleep(0.0005)
            if k % 50 == 0:
                worst_queue = max(worst_queue, *(p["queued"] for p in server.counters()["pdcs"]))
        wait_for(lambda: len(received) == len(baseline_received) == 1500 * 52)
        reader.stop()
        baseline_reader.stop()
        counters = server.counters()
        stalled_pdc = next(p for p in counters["pdcs"] if p["data_on"])
        stalled.close()
    assert stalled_pdc["frames_dropped"] > 1000 and stalled_pdc["queued"] <= 50 and worst_queue <= 50
    assert counters["frames_dropped"] == stalled_pdc["frames_dropped"]
    assert reader.counters()["rejected"] == {} and counters["handoff_dropped"] == 0
    # The hand-off adds a deque append and at most one non-blocking send: never the wait of a blocking one.
    assert np.median(offer_s) <= 2 * np.median(baseline_s) + 50e-6, (np.median(offer_s), np.median(baseline_s))
    assert np.percentile(offer_s, 99) <= 2 * np.percentile(baseline_s, 99) + 1e-3
    # A send that waited on the stalled PDC would wait on every offer once its buffers are full (the p99 above) or
    # for good; one offer held up by the scheduler (1.49 s once, in a clean-clone suite on a loaded 2-core host,
    # the other 1499 in 0.1-0.3 ms) is not one.
    assert sum(t >= 0.5 for t in offer_s) <= 1 + sum(t >= 0.5 for t in baseline_s), "offers waited on the stalled PDC"


def _open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def test_a_hundred_connect_disconnect_cycles_leave_nothing_behind(server):
    fds_before = _open_fds()
    for cycle in range(100):
        with connect(server) as sock:
            if cycle % 2:
                sock.sendall(command(c37.Command.SEND_CFG2) + command(c37.Command.DATA_ON))
            if cycle % 3 == 0:
                sock.sendall(command(c37.Command.SEND_CFG2)[:7])  # cut short: truncated when it goes away
        server.offer(EPOCH_NS + cycle * 20_000_000, plant_values(3, cycle))
    wait_for(lambda: server.counters()["disconnected"] == 100)
    counters = server.counters()
    assert counters["connections"] == 100 and counters["connected"] == 0 and counters["pdcs"] == []
    assert counters["rejected"].get("truncated", 0) >= 1
    assert len(server._pdcs) == 0 and server._streaming == 0
    assert _open_fds() <= fds_before
    with connect(server) as sock:
        sock.sendall(command(c37.Command.SEND_CFG2))
        assert c37.decode_config(read_frame(sock)).config == server.config
    assert sum(1 for line in server.events() if line.endswith("connected")) == 101


def test_connections_beyond_the_limit_are_refused_and_counted():
    with PmuServer(plant_config(1), HEADER, port=0, max_clients=2) as server:
        socks = [connect(server) for _ in range(3)]
        wait_for(lambda: server.counters()["refused"] == 1)
        assert socks[2].recv(10) == b""
        assert server.counters()["connected"] == 2
        for sock in socks:
            sock.close()


def test_a_rate_c37118_does_not_allow_is_refused():
    with pytest.raises(ValueError, match="10, 25, 50, 100"):
        PmuServer(plant_config(1, rate=30), HEADER, port=0)


def test_stop_closes_everything(server):
    sock = connect(server)
    wait_for(lambda: server.counters()["connected"] == 1)
    address = server.address
    server.stop()
    assert sock.recv(10) == b""
    sock.close()
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(address, timeout=1)
    assert server.counters()["disconnected"] == 1
    server.stop()
