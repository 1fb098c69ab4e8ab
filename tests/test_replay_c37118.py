"""``nni-replay FILE --pmu-server``: a recording served as IEEE C37.118.2 at its rate, read by two PDCs.

* pyc37's ``Pdc`` (an independent implementation) reads a shipped lockstep
  SMIB recording's stream: CFG-2 and the header (which say what the stream
  leaves out), then every sample, each frame's angle the recording's rotor
  angle at its stamp (the simulated clock from the profile's epoch) to
  float32 precision, paced at the recorded 50 frames/s in wall time.
* Our client core reads a realtime Kundur recording (4 generators, 30
  frames/s at 60 Hz, one sample missing for one generator): a station per
  namespace named as the network plant names it, the recorded wall-clock
  instants, angles, FREQ from the recorded speed, the P_E and P_ST analogs as
  recorded, terminal V/I from the recorded true angles and scenario; the
  missing sample is "do not use" in STAT for that station alone. Without the
  fault's instant (a service call's) the terminal phasors are left out.
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
from nni_battery_controller.network_deployment import plant_parameters
from nni_msgs_adapter.c37118.client import PdcClient
from nni_msgs_adapter.c37118.profile import LOCKSTEP_EPOCH_NS
from nni_msgs_adapter.recording.mcap_io import Ros2McapWriter, qos_profiles_yaml, read_recording
from nni_battery_controller.replay_c37118 import RecordedStream
from nni_msgs_adapter.recording.runs import RUN_METADATA_NAME, run_metadata
from nni_msgs_adapter.ros import contract
from nni_plant_sim.cases import load_network
from nni_plant_sim.network_plant_config import parameters as network_parameters
from nni_plant_sim.network_plant_config import scenario_from as network_scenario_from
from nni_plant_sim.network_scenarios import AngleDisplacement
from nni_plant_sim.phasors import terminal_phasors
from nni_plant_sim.scenarios import StartingAt
from pyc37.frame import DataFrame as PyData
from pyc37.pdc import Pdc
from rclpy.serialization import serialize_message

NNI_REPLAY = Path(sys.executable).parent / "nni-replay"
SHIPPED = Path(__file__).resolve().parent.parent / "recordings" / "paper_b0.3.mcap"
LISTENING = "  C37.118 stream listening on "
REALTIME_START_NS = 1_796_000_000 * 1_000_000_000
KUNDUR_PERIOD_NS = round(1e9 / 30)
FLOAT32 = 4e-7
#: A bus fault at bus 7 cleared after 0.1 s, as nni-demo --case records it (network_deployment.scenario_parameters).
BUS_FAULT = {"scenario": "bus_fault", "fault_bus": 7, "fault_r": 0.0, "fault_x": 0.0, "clearing_time": 0.1}


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
            (stamp, delta, speed), (p_elec,), _seal = contract.pmu_from_bytes(record.cdr_bytes)
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
                 missing: tuple = (), metadata: bool = True, fault_at_start: bool = True) -> None:
    """A realtime Kundur run's pmu and plant states (4 generators), wall-clock stamps, ``missing`` (ns, k) left out;
    its run parameters as nni-demo --case records them (``network_plant``), or without the case and with
    ``f0`` as a SMIB's (``plant``)."""
    with Ros2McapWriter(path, flush_period_s=3600.0) as writer:
        if metadata:  # what nni-demo --case records: the parameters it sets (the node's defaults for the rest)
            plant = plant_parameters("kundur_two_area", BUS_FAULT, "realtime", rate_hz, samples / rate_hz, [0.1] * 4)
            plant.update({} if fault_at_start else {"fault_at_start": False})  # as a logger started by hand
            run = {"case": "kundur_two_area", "mode": "realtime", "rate_hz": rate_hz, "network_plant": plant}
            if f0 is not None:
                run = {"mode": "realtime", "rate_hz": rate_hz, "plant": {"f0_hz": f0}}
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
                delta, speed = true_angle(i, k) + 0.001, 0.1 * math.sin(0.2 * k + i)  # measured: off the true
                writer.write(channels[i, contract.TOPIC_PMU],
                             serialize_message(contract.pmu_message(stamp, delta, speed, 0.7 + 0.01 * i)), stamp, stamp)
                writer.write(channels[i, contract.TOPIC_PLANT_STATE],
                             serialize_message(contract.plant_state_message(stamp, true_angle(i, k), speed, -0.02 * i)),
                             stamp, stamp)


def true_angle(i: int, k: int) -> float:
    return 0.3 * i + 0.05 * k


def kundur_stream(tmp_path, **write) -> tuple[str, list, dict, PdcClient]:
    """nni-replay's output, what our client read and the recording's pmu samples of a Kundur recording."""
    path = tmp_path / "kundur.mcap"
    write_kundur(path, 60, **write)
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
    return out, samples, recorded_pmu(path), client


def test_our_client_reads_a_realtime_network_recording_a_station_per_generator(tmp_path):
    out, samples, recorded, client = kundur_stream(tmp_path, missing={(3, 10)})
    assert "60 samples of 4 station(s) at 30 frames/s (realtime), C37.118 IDCODE 9" in out
    config = client.session.config
    assert [station.name for station in config.stations] == [f"gen{i} G{i} bus {i}" for i in range(1, 5)]
    assert config.data_rate == 30 and [len(s.phasors) for s in config.stations] == [3] * 4
    # Without gen3's angle at sample 10 no machine's terminal current is known there: all four "do not use".
    assert len(samples) == 4 * 59 and client.counters()["rejected"] == {"invalid_data": 4}
    net = load_network("kundur_two_area")
    fault = StartingAt(network_scenario_from(net, {**{spec.name: spec.default for spec in network_parameters()},
                                                   **BUS_FAULT}), 0.0, AngleDisplacement(np.zeros(4)))
    for sample in samples:
        namespace = f"/gen{sample.station + 1}"
        stamp = next(s for s in recorded[namespace] if abs(s - sample.instant_ns) <= 500)  # to the microsecond
        delta, speed, p_elec = recorded[namespace][stamp]
        assert abs(wrapped(sample.reading.angles_rad[0] - delta)) <= FLOAT32
        assert sample.reading.frequency_hz == pytest.approx(60.0 + speed / (2 * math.pi), abs=1e-3)  # mHz steps
        assert sample.reading.analogs == pytest.approx((p_elec, -0.02 * (sample.station + 1)), rel=1e-6)
        # V_t as the network plant computes it, at the true angles, with the bus fault on until 0.1 s.
        k = round((stamp - 137 - REALTIME_START_NS) / KUNDUR_PERIOD_NS)
        true = np.array([true_angle(i, k) for i in range(1, 5)])
        _, _, voltage = terminal_phasors(net, fault.network(k / 30, net)[1], true)
        assert sample.reading.magnitudes[1] == pytest.approx(abs(voltage[sample.station]), rel=1e-6), k
        assert abs(wrapped(sample.reading.angles_rad[1] - np.angle(voltage[sample.station]))) <= FLOAT32
    invalid_at = REALTIME_START_NS + 10 * KUNDUR_PERIOD_NS + 137
    assert not any(abs(s.instant_ns - invalid_at) <= 500 for s in samples)


def test_a_recording_without_the_fault_s_instant_leaves_the_terminal_phasors_out_and_says_why(tmp_path):
    out, samples, recorded, client = kundur_stream(tmp_path, fault_at_start=False, missing={(3, 10)})
    assert [len(s.phasors) for s in client.session.config.stations] == [1] * 4
    assert all(len(sample.reading.angles_rad) == 1 for sample in samples)
    # EMF only: the sample gen3 lacks is "do not use" for gen3 alone.
    assert len(samples) == 4 * 60 - 1 and client.counters()["rejected"] == {"invalid_data": 1}
    invalid_at = REALTIME_START_NS + 10 * KUNDUR_PERIOD_NS + 137
    assert not any(s.station == 2 and abs(s.instant_ns - invalid_at) <= 500 for s in samples)
    assert "turned data on" in out
    recording = read_recording(tmp_path / "kundur.mcap")
    header = RecordedStream(recording, run_metadata(recording)).header("kundur.mcap")
    assert "Left out: terminal V/I (the run's disturbance started at a service call, whose instant the recording " \
           "does not hold)" in header


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
