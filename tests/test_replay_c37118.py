"""``nni-replay FILE --pmu-server``: a recording served as IEEE C37.118.2 at its rate, read by two PDCs.

* pyc37's ``Pdc`` (an independent implementation) reads a shipped lockstep
  SMIB recording's stream: CFG-2 and the header (which say what the stream
  leaves out), then every sample, each frame's angle the recording's rotor
  angle at its stamp (the simulated clock from the profile's epoch) to
  float32 precision, paced at the recorded 50 frames/s in wall time.
* Our client core reads a realtime Kundur recording (4 generators, 30
  frames/s at 60 Hz, one sample missing for one generator): a station per
  namespace named as the network plant names it, the recorded wall-clock
  instants, angles, FREQ from the recorded speed and the P_E analog as
  recorded; the missing sample is "do not use" in STAT for that station alone.
* What cannot be streamed, and options that do not go with ``--pmu-server``,
  are refused in one line, exit 2.
"""

from __future__ import annotations

import json
import math
import select
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import c37118_cases  # noqa: F401  (pyc37 needs collections.abc loaded first)
from nni_msgs_adapter.c37118.client import PdcClient
from nni_msgs_adapter.c37118.profile import LOCKSTEP_EPOCH_NS
from nni_msgs_adapter.recording.mcap_io import Ros2McapWriter, qos_profiles_yaml, read_recording
from nni_msgs_adapter.recording.runs import RUN_METADATA_NAME
from nni_msgs_adapter.ros import contract
from pyc37.frame import DataFrame as PyData
from pyc37.pdc import Pdc
from rclpy.serialization import serialize_message

NNI_REPLAY = Path(sys.executable).parent / "nni-replay"
SHIPPED = Path(__file__).resolve().parent.parent / "recordings" / "paper_b0.3.mcap"
LISTENING = "  C37.118 stream listening on "
REALTIME_START_NS = 1_796_000_000 * 1_000_000_000
KUNDUR_PERIOD_NS = round(1e9 / 30)
FLOAT32 = 4e-7


def start_replay(*args) -> tuple[subprocess.Popen, int, list]:
    """nni-replay serving on a free loopback port, that port (from its listening line) and the lines up to it."""
    replay = subprocess.Popen([str(NNI_REPLAY), *map(str, args), "--pmu-server", "0"], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    lines = []
    while True:
        line = replay.stdout.readline()
        assert line, f"nni-replay ended first: {replay.stderr.read()}"
        lines.append(line)
        if line.startswith(LISTENING):
            host, port = line[len(LISTENING):].strip().rsplit(":", 1)
            assert host == "127.0.0.1"
            return replay, int(port), lines


def finish(replay: subprocess.Popen, lines: list) -> str:
    out, err = replay.communicate(timeout=60)
    assert replay.returncode == 0, err
    return "".join(lines) + out


def wrapped(angle):
    return (np.asarray(angle) + math.pi) % (2 * math.pi) - math.pi


def recorded_pmu(path: Path) -> dict:
    """Per namespace, stamp -> (delta, speed, P_E) of the recording's pmu messages."""
    out: dict = {}
    for record in read_recording(path).messages:
        if record.topic.endswith("/" + contract.TOPIC_PMU) or record.topic == "/" + contract.TOPIC_PMU:
            (stamp, delta, speed), (p_elec,) = contract.pmu_from_bytes(record.cdr_bytes)
            out.setdefault(record.topic[: -len(contract.TOPIC_PMU) - 1], {})[stamp] = (delta, speed, p_elec)
    return out


def test_pyc37_reads_a_shipped_recording_at_its_rate_with_its_rotor_angles():
    replay, port, lines = start_replay(SHIPPED, "--pmu-wait-for-pdcs", "1")
    try:
        pdc = Pdc(pdc_id=1, pmu_ip="127.0.0.1", pmu_port=port, buffer_size=4)  # see tests/test_c37118_demo.py
        pdc.logger.setLevel("ERROR")
        pdc.run()
        assert pdc.get_config("cfg2").get_station_name().rstrip() == "SMIB generator"
        header = pdc.get_header().get_header()
        assert "paper_b0.3.mcap: a lockstep recording of the SMIB generator" in header
        assert "Left out: terminal V/I" in header
        pdc.start()
        frames, arrivals = [], []
        while True:
            readable, _, _ = select.select([pdc.pmu_socket], [], [], 30.0)
            assert readable, "no frame for 30 s"
            if not pdc.pmu_socket.recv(1, socket.MSG_PEEK):
                break
            frames.append(pdc.get())
            arrivals.append(time.monotonic())
        pdc.quit()
        out = finish(replay, lines)
    finally:
        if replay.poll() is None:
            replay.kill()
            replay.wait()
    assert " connected" in out and "turned data on" in out and "went away" in out
    recorded = recorded_pmu(SHIPPED)[""]
    assert all(isinstance(frame, PyData) for frame in frames) and len(frames) == len(recorded) == 500
    assert f"500 frames offered; PDC 127.0.0.1:" in out and "sent 502, dropped 0" in out  # CFG-2 and header too
    instants = []
    for frame in frames:
        measured = frame.get_measurements()
        (station,) = measured["measurements"]
        stamp_ns = round(measured["time"] * 1e6) * 1000 - LOCKSTEP_EPOCH_NS  # lockstep: the epoch taken off
        delta, speed, p_elec = recorded[stamp_ns]
        assert abs(wrapped(station["phasors"][0][1] - delta)) <= FLOAT32, stamp_ns
        assert station["analog"][0] == pytest.approx(p_elec, rel=1e-6, abs=1e-6)
        instants.append(stamp_ns)
    assert instants == sorted(recorded)
    # Paced at 50 frames/s in wall time: 10 s of simulated time take 10 s (the lockstep run took 1.3 s).
    span_s = arrivals[-1] - arrivals[0]
    assert 0.95 * 499 / 50 <= span_s <= 499 / 50 + 3.0, span_s


def write_kundur(path: Path, samples: int, *, rate_hz: float = 30.0, f0: float | None = None,
                 missing: tuple = (), metadata: bool = True) -> None:
    """A realtime Kundur run's pmu and plant states (4 generators), wall-clock stamps, ``missing`` (ns, k) left out."""
    with Ros2McapWriter(path, flush_period_s=3600.0) as writer:
        if metadata:
            plant = {"mode": "realtime", "pmu_rate_hz": rate_hz, "scenario": "bus_fault", "fault_at_start": True}
            run = {"case": "kundur_two_area", "mode": "realtime", "rate_hz": rate_hz, "plant": plant}
            if f0 is not None:
                run = {"mode": "realtime", "rate_hz": rate_hz, "plant": {**plant, "f0_hz": f0}}
            writer.add_metadata(RUN_METADATA_NAME, {key: json.dumps(value) for key, value in run.items()})
        channels = {}
        for i in range(1, 5):
            for name in (contract.TOPIC_PMU, contract.TOPIC_PLANT_STATE):
                channels[i, name] = writer.add_channel(f"/gen{i}/{name}", contract.TOPICS[name][0],
                                                       qos_profiles_yaml([contract.TOPICS[name][2]]))
        for k in range(samples):
            stamp = REALTIME_START_NS + k * KUNDUR_PERIOD_NS + 137  # wall-clock instants: no whole microsecond
            for i in range(1, 5):
                if (i, k) in missing:
                    continue
                delta, speed = 0.3 * i + 0.05 * k, 0.1 * math.sin(0.2 * k + i)
                writer.write(channels[i, contract.TOPIC_PMU],
                             serialize_message(contract.pmu_message(stamp, delta, speed, 0.7 + 0.01 * i)), stamp, stamp)
                writer.write(channels[i, contract.TOPIC_PLANT_STATE],
                             serialize_message(contract.plant_state_message(stamp, delta, speed, -0.02 * i)),
                             stamp, stamp)


def test_our_client_reads_a_realtime_network_recording_a_station_per_generator(tmp_path):
    path = tmp_path / "kundur.mcap"
    write_kundur(path, 60, missing={(3, 10)})
    samples, lock = [], threading.Lock()

    def take(batch):
        with lock:
            samples.extend(batch)

    replay, port, lines = start_replay(path, "--pmu-wait-for-pdcs", "1", "--pmu-idcode", "9")
    client = PdcClient("127.0.0.1", port, 9, take)
    client.start()
    try:
        out = finish(replay, lines)
    finally:
        client.stop()
        if replay.poll() is None:
            replay.kill()
            replay.wait()
    assert "60 samples of 4 station(s) at 30 frames/s (realtime), C37.118 IDCODE 9" in out
    recorded = recorded_pmu(path)
    config = client.session.config
    assert [station.name for station in config.stations] == [f"gen{i} G{i} bus {i}" for i in range(1, 5)]
    assert config.data_rate == 30 and [len(s.phasors) for s in config.stations] == [1] * 4  # no terminal V/I
    assert len(samples) == 4 * 60 - 1 and client.counters()["rejected"] == {"invalid_data": 1}
    for sample in samples:
        namespace = f"/gen{sample.station + 1}"
        stamp = next(s for s in recorded[namespace] if abs(s - sample.instant_ns) <= 500)  # to the microsecond
        delta, speed, p_elec = recorded[namespace][stamp]
        assert abs(wrapped(sample.reading.angles_rad[0] - delta)) <= FLOAT32
        assert sample.reading.frequency_hz == pytest.approx(60.0 + speed / (2 * math.pi), abs=1e-3)  # mHz steps
        assert sample.reading.analogs[0] == pytest.approx(p_elec, rel=1e-6)
    invalid_at = REALTIME_START_NS + 10 * KUNDUR_PERIOD_NS + 137
    assert not any(s.station == 2 and abs(s.instant_ns - invalid_at) <= 500 for s in samples)


@pytest.mark.parametrize("write, args, message", [
    (dict(rate_hz=50.0), [], "--pmu-server: reporting rate 50 frames/s is not one C37.118 allows at 60 Hz"),
    (dict(f0=55.0), [], "--pmu-server: a C37.118 stream needs a nominal frequency of 50 or 60 Hz, got 55 Hz"),
    (dict(metadata=False), [], "holds no run parameters (nni_run)"),
    (dict(), ["--pmu-idcode", "0"], "--pmu-idcode must be within 1..65534"),
    (dict(), ["--pmu-wait-for-pdcs", "65"], "--pmu-wait-for-pdcs must be within 0..64"),
    (dict(), ["--rate", "2"], "--rate: ROS playback options, not for --pmu-server"),
    (dict(), ["--loop", "--domain-id", "52"], "--loop, --domain-id: ROS playback options, not for --pmu-server"),
    (dict(), ["--ros-args", "-r", "a:=b"], "--ros-args: ROS playback options, not for --pmu-server"),
    (dict(), ["--f0-hz", "60"], "--f0-hz: a Rerun option, not for --pmu-server"),
    (dict(), ["--info"], "--pmu-server: not with --rrd/--connect/--spawn/--info/--plot"),
    (dict(), ["--rrd", "OUT.rrd"], "--pmu-server: not with --rrd/--connect/--spawn/--info/--plot"),
    (dict(), ["--plot", "OUT.png"], "--pmu-server: not with --rrd/--connect/--spawn/--info/--plot"),
    (dict(), ["--connect"], "--pmu-server: not with --rrd/--connect/--spawn/--info/--plot"),
])
def test_what_cannot_be_streamed_is_refused_in_one_line(tmp_path, write, args, message):
    path = tmp_path / "kundur.mcap"
    write_kundur(path, 3, **write)
    args = [str(tmp_path / arg) if arg.startswith("OUT.") else arg for arg in args]
    result = subprocess.run([str(NNI_REPLAY), str(path), "--pmu-server", "0", *args], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 2 and result.stdout == "", result.stdout + result.stderr
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("nni-replay: error: ")
    assert message in result.stderr, result.stderr
    assert not list(tmp_path.glob("OUT.*"))


@pytest.mark.parametrize("args, message", [
    (["--pmu-idcode", "3"], "--pmu-idcode applies to a C37.118 stream only (--pmu-server [HOST:]PORT)"),
    (["--pmu-wait-for-pdcs", "1", "--info"], "--pmu-wait-for-pdcs applies to a C37.118 stream only"),
    (["--pmu-server", "host:port"], "a C37.118 server address is [HOST:]PORT"),
])
def test_stream_options_are_checked_as_nni_demo_checks_them(args, message):
    result = subprocess.run([str(NNI_REPLAY), str(SHIPPED), *args], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.count("\n") == 1 and message in result.stderr, result.stderr
