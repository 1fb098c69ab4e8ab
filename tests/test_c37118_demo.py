"""The user's flow with ``nni-demo --pmu-server``: a PDC on a real realtime run, over the loopback.

* pyc37's ``Pdc`` (an independent implementation) connects to a 3 s SMIB run,
  gets CFG-2 and the header, turns data on and reads >= 99 % of the run's
  frames; each frame's angle is the recording's rotor angle at the same
  instant to float32 precision. The same session, captured on ``lo`` by
  dumpcap (as root), is decoded by tshark: no malformed frame, the right count
  of each type.
* IEEE 39 (10 stations) at 60 frames/s (50 is no C37.118 rate at 60 Hz) for
  30 s with two PDCs: our client core reads every frame; the other turns data
  on and never reads: its frames are dropped for it alone (counted), what the
  server holds for it stays bounded, the plant takes every sample, and the
  loop's misses once that PDC's frames are dropped are those before.
* What cannot be asked for is refused in one line, before anything starts.
"""

from __future__ import annotations

import json
import math
import select
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

import c37118_cases  # noqa: F401  (pyc37 needs collections.abc loaded first)
from nni_msgs_adapter.c37118 import frames as c37
from nni_msgs_adapter.c37118.client import PdcClient
from nni_msgs_adapter.c37118.server import SEND_BUFFER_BYTES
from nni_msgs_adapter.recording.runs import read_generator_run, read_generator_runs
from pyc37.frame import DataFrame as PyData
from pyc37.pdc import Pdc
from rosproc import fresh_domain_id, ros_env

pytestmark = pytest.mark.ros

DEMO = Path(sys.executable).parent / "nni-demo"
LISTENING = "  C37.118 stream listening on "


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def start_demo(args, domain: int, out: Path) -> subprocess.Popen:
    return subprocess.Popen([str(DEMO), *args, "--out", str(out), "--domain-id", str(domain)], env=ros_env(domain),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def stream_address(demo: subprocess.Popen, lines: list, timeout_s: float = 120.0) -> tuple[str, int]:
    """Read the demo's output up to the line that says where its run's stream listens."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = demo.stdout.readline()
        assert line, f"the demo ended first: {demo.stderr.read()}"
        lines.append(line)
        if line.startswith(LISTENING):
            host, port = line[len(LISTENING):].strip().rsplit(":", 1)
            return host, int(port)
    raise AssertionError("the demo did not say where its stream listens")


def finish(demo: subprocess.Popen, lines: list, timeout_s: float) -> None:
    out, err = demo.communicate(timeout=timeout_s)
    lines.extend(out.splitlines(keepends=True))
    assert demo.returncode == 0, err


def read_until_closed(pdc: Pdc) -> list:
    """pyc37's frames until the server closes the connection (pyc37's get() spins on a closed socket)."""
    frames = []
    while True:
        readable, _, _ = select.select([pdc.pmu_socket], [], [], 30.0)
        assert readable, "no frame for 30 s"
        if not pdc.pmu_socket.recv(1, socket.MSG_PEEK):
            return frames
        frames.append(pdc.get())


def wrapped(angle):
    return (np.asarray(angle) + math.pi) % (2 * math.pi) - math.pi


def tshark(*args) -> str:
    result = subprocess.run(["tshark", *args], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_pyc37_reads_a_realtime_demo_run_and_tshark_decodes_its_capture(tmp_path):
    assert shutil.which("dumpcap") and shutil.which("tshark"), "scripts/system-deps installs tshark (as root)"
    port, capture = free_port(), tmp_path / "lo.pcapng"
    dumpcap = subprocess.Popen(["dumpcap", "-q", "-i", "lo", "-f", f"tcp port {port}", "-w", str(capture)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 20
        while not capture.exists() and time.monotonic() < deadline:  # dumpcap creates the file once it captures
            time.sleep(0.05)
        assert capture.exists(), "dumpcap did not start capturing"
        lines = []
        demo = start_demo(["--mode", "realtime", "--b", "0.3", "--duration", "3", "--pmu-server", str(port),
                           "--pmu-wait-for-pdcs", "1"], fresh_domain_id(), tmp_path / "out")
        try:
            assert stream_address(demo, lines) == ("127.0.0.1", port)
            # pyc37 reads buffer_size bytes at a time and drops both frames when one read takes two (a PDC
            # behind by a frame): 4 makes it read a frame's SYNC and size, then no further than its end.
            pdc = Pdc(pdc_id=1, pmu_ip="127.0.0.1", pmu_port=port, buffer_size=4)
            pdc.logger.setLevel("ERROR")
            pdc.run()
            cfg = pdc.get_config("cfg2")
            assert cfg.get_station_name().rstrip() == "SMIB generator"  # pyc37: a string for one station
            assert "SMIB generator" in pdc.get_header().get_header()
            pdc.start()  # data on: the run starts now (it waits for one PDC)
            frames = read_until_closed(pdc)
            pdc.quit()
            finish(demo, lines, 180)
        finally:
            if demo.poll() is None:
                demo.kill()
                demo.wait()
    finally:
        time.sleep(0.5)  # the last segments reach the capture
        dumpcap.send_signal(signal.SIGTERM)
        dumpcap.wait(timeout=20)
    text = "".join(lines)
    assert "C37.118: PDC 127.0.0.1:" in text and " connected" in text and "turned data on" in text
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())["scenarios"][0]
    stream = summary["c37118"]
    (served,) = stream["pdcs"]
    assert stream["address"] == f"127.0.0.1:{port}" and served["frames_dropped"] == 0
    assert f"C37.118 stream 127.0.0.1:{port}: {stream['offered']} frames offered; PDC {served['address']} sent " \
           f"{served['frames_sent']}, dropped 0" in text
    data = [frame for frame in frames if isinstance(frame, PyData)]
    assert len(data) == len(frames), "every frame decoded"
    # 3 s at 50/s; a loaded machine makes the realtime plant skip reporting instants (141 once, in a clean-clone suite).
    assert stream["offered"] >= 0.9 * 3 * 50 and len(data) >= 0.99 * stream["offered"], (len(data), stream["offered"])
    run = read_generator_run(Path(summary["recording"]))
    recorded = dict(zip((run.stamp_ns + 500) // 1000, run.delta_rad))  # to the microsecond, as on the wire
    matched = 0
    for frame in data:
        measured = frame.get_measurements()
        (station,) = measured["measurements"]
        instant_us = round(measured["time"] * 1e6)
        if instant_us in recorded:
            matched += 1
            assert abs(wrapped(station["phasors"][0][1] - recorded[instant_us])) <= 4e-7, instant_us  # float32
    assert matched >= 0.99 * len(data), (matched, len(data))

    decode = ["-r", str(capture), "-d", f"tcp.port=={port},synphasor"]
    rows = tshark(*decode, "-Y", "synphasor", "-T", "fields", "-E", "occurrence=a", "-E", "aggregator=;",
                  "-e", "synphasor.frtype", "-e", "synphasor.command")
    types, commands = Counter(), Counter()
    for row in rows.splitlines():
        frame_types, cmds = row.split("\t")
        types.update(int(t, 0) for t in frame_types.split(";"))
        commands.update(int(c, 0) for c in cmds.split(";") if c)
    # tshark numbers frame types as SYNC does: 0 data, 1 header, 3 CFG-2, 4 command. pyc37 asked CFG-2, the
    # header, data on (its quit closes the socket without a data off).
    assert types == {0: served["frames_sent"] - 2, 1: 1, 3: 1, 4: 3}, types
    assert commands == {5: 1, 3: 1, 2: 1}
    assert tshark(*decode, "-Y", "_ws.malformed || _ws.expert.severity >= error || synphasor.data.unknown") == ""


def stalled_pdc(host: str, port: int) -> socket.socket:
    """A PDC that turns data on and never reads: a small receive buffer, so that the server's backlog grows."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect((host, port))
    sock.sendall(c37.encode_command(1, c37.Command.DATA_ON, time.time_ns()))
    return sock


def test_ieee39_for_30_s_loses_no_frame_and_a_pdc_that_never_reads_costs_the_loop_nothing(tmp_path):
    lines, instants, lock = [], Counter(), threading.Lock()

    def take(samples):
        with lock:
            instants.update(sample.instant_ns for sample in samples)

    # Composed controllers: the stream is what is judged, and one process starts in a tenth of the CPU of ten.
    demo = start_demo(["--case", "ieee39", "--deployment", "composed", "--mode", "realtime", "--rate", "60",
                       "--b", "0.1", "--duration", "30", "--pmu-server", "0", "--pmu-wait-for-pdcs", "2"],
                      fresh_domain_id(), tmp_path / "out")
    try:
        host, port = stream_address(demo, lines)
        assert host == "127.0.0.1" and port > 0, "port 0: the plant picks one and the demo says which"
        reader = PdcClient(host, port, 1, take)
        reader.start()
        stalled = stalled_pdc(host, port)
        stalled_port = stalled.getsockname()[1]
        try:
            finish(demo, lines, 400)
        finally:
            reader.stop()
            stalled.close()
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.wait()
    result = json.loads((tmp_path / "out" / "summary.json").read_text())["runs"][0]
    stream = result["c37118"]
    offered, misses = stream["offered"], {ns: g["dropped_samples"] for ns, g in result["generators"].items()}
    published = {g["logger_counts"][f"/{ns}/pmu"] for ns, g in result["generators"].items()}
    # Every measurement the plant published on ROS went to the stream too (the demo checked the recording
    # holds them all); a loaded machine makes the realtime plant skip reporting instants (a clean-clone
    # suite on a slow host: 1613 of 1800). A plant held up by the stalled PDC would stop near the frames
    # that PDC was sent before its buffers filled (963 in that run) plus the server's queue of 100.
    assert published == {offered} and offered >= 0.8 * 30 * 60, (offered, published, misses)
    # Every frame reached the reading PDC, each with all 10 stations.
    assert len(instants) == offered and set(instants.values()) == {10}, (len(instants), offered)
    runs = read_generator_runs(Path(result["recording"]))
    recorded = {int(stamp) for stamp in (runs["/gen1"].stamp_ns + 500) // 1000}  # to the microsecond
    assert {(instant + 500) // 1000 for instant in instants} <= recorded, "each frame is a recorded sample's"
    by_port = {pdc["address"]: pdc for pdc in stream["pdcs"]}
    (stalled_counts,) = [pdc for address, pdc in by_port.items() if address.endswith(f":{stalled_port}")]
    # The PDC that never read: its frames were dropped for it alone, what it was sent bounded by the buffers.
    assert stalled_counts["frames_dropped"] > 0
    assert stalled_counts["frames_sent"] + stalled_counts["frames_dropped"] == offered
    assert stalled_counts["bytes_sent"] <= 2 * SEND_BUFFER_BYTES + 256 * 1024
    assert stream["handoff_dropped"] == 0
    # The loop's misses (a controller's answer not in by the next sample: the machine's load) before the
    # stalled PDC's buffers filled and once its frames were being dropped: the same, within what the load's
    # drift over 30 s gives. A stream that slowed the plant would have cost samples (counted above) and left
    # the later ones unanswered.
    filled = stalled_counts["frames_sent"] + 100  # its kernel buffers, then the server's queue of 100 frames
    for ns, run in runs.items():
        unanswered = ~run.answered[:-1]  # the last state answers no sample
        before, after = unanswered[:stalled_counts["frames_sent"]].mean(), unanswered[filled:].mean()
        assert after <= before + 0.1, (ns, before, after, misses)


@pytest.mark.parametrize("args, message", [
    (["--pmu-wait-for-pdcs", "1"], "--pmu-wait-for-pdcs applies to a C37.118 stream only"),
    (["--case", "kundur_two_area", "--pmu-idcode", "3"], "--pmu-idcode applies to a C37.118 stream only"),
    (["--pmu-server", "0", "--rate", "20"], "reporting rate 20 frames/s is not one C37.118 allows at 50 Hz"),
    (["--case", "ieee39", "--pmu-server", "0"], "reporting rate 50 frames/s is not one C37.118 allows at 60 Hz"),
    (["--pmu-server", "host:port"], "a C37.118 server address is [HOST:]PORT"),
    (["--pmu-server", "0", "--pmu-idcode", "0"], "--pmu-idcode must be within 1..65534"),
])
def test_what_a_stream_cannot_be_is_refused_in_one_line(tmp_path, args, message):
    result = subprocess.run([str(DEMO), *args, "--out", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.count("\n") == 1 and message in result.stderr, result.stderr
