"""The MCAP logger and nni-replay as real processes over Fast DDS on localhost.

(a) a logger killed with SIGKILL leaves a file that yields every message up to its last flush;
(b) SIGINT and SIGTERM finish the file and the counts the logger prints are the file's;
(c) one logger records generators in two namespaces into one file;
(d) a replayed recording reaches a subscriber byte for byte, in order, with its timing;
    --start-offset, --clock and --loop do what they say; by default it waits for a subscriber,
    and one that takes a single topic is enough;
(e) bad input to nni-replay and the logger: one line, non-zero exit, no traceback, no output;
(f) a recording describes itself: the run's parameters (nni_run), rosbag2's metadata (ROS distro),
    `nni-replay --info` and `--plot`; diagnostics on /diagnostics name their generator.
"""

from __future__ import annotations

import dataclasses
import json
import math
import signal
import socket
import subprocess
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap.writer import Writer
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock

from nni_msgs_adapter.ros import contract
from nni_battery_controller.demo_common import plant_summary
from nni_battery_controller.verdicts import Outcome
from nni_msgs_adapter.recording.mcap_io import MCAP_MAGIC, Ros2McapWriter, deserialize, qos_profiles_yaml, read_messages
from nni_msgs_adapter.ros.defaults import controller_defaults, logger_defaults, plant_defaults
from nni_msgs_adapter.recording.mcap_logger import COUNTS_PREFIX
from nni_msgs_adapter.recording.runs import RUN_METADATA_NAME, read_generator_runs
from rosproc import NodeProcess, Probe, busy_processes, fresh_domain_id, node_processes, ros_env, sealed_pmu

pytestmark = pytest.mark.ros

PLANT = "nni_plant_sim.plant_node"
CONTROLLER = "nni_battery_controller.controller_node"
LOGGER = "nni_msgs_adapter.recording.mcap_logger"
NNI_REPLAY = Path(sys.executable).parent / "nni-replay"
RECORDINGS = Path(__file__).resolve().parent.parent / "recordings"
RATE_HZ = 50.0
FLUSH_PERIOD_S = logger_defaults()["flush_period_s"]
# The logger receives a sample after the plant sent it (its DDS source timestamp) and the flush
# itself takes time: on a loaded 2-core machine that is up to tens of ms; 0.25 s covers it with margin.
RECEIVE_SKEW_S = 0.25
NAMESPACES = {"/gen1": 0.3, "/gen2": math.inf}


def fully_qualified(topic: str, namespace: str = "") -> str:
    """``pmu`` -> ``/pmu`` (or ``/gen1/pmu``); ``/clock`` stays."""
    return topic if topic.startswith("/") else f"{namespace}/{topic}"


class RawProbe(Probe):
    """A Probe whose messages are ``(writer's source timestamp ns, CDR bytes as received)``.

    Raw subscriptions: the bytes are those on the wire, padding included, which a
    deserialise-serialise round trip would not keep. The time is the one DDS stamps (wall
    clock) when the writer sent the sample, so the pacing judged is the writer's: this
    process's own delays under load (its spin thread preempted) do not enter it.
    """

    def __init__(self, domain_id: int, topics):
        super().__init__(domain_id, ())
        for topic in topics:
            self.messages[topic] = []
            msg_class, name, qos = contract.recorder_endpoint(topic)
            self.node.create_subscription(msg_class, name, self._recorder(topic), qos, raw=True)

    def _recorder(self, topic):
        record = super()._recorder(topic)
        return lambda cdr, info: record((info["source_timestamp"], cdr))


def file_counts(path: Path) -> dict[str, int]:
    return dict(Counter(record.topic for record in read_messages(path)))


def printed_counts(output: str) -> dict[str, int]:
    [line] = [line for line in output.splitlines() if line.startswith(COUNTS_PREFIX)]
    return json.loads(line[len(COUNTS_PREFIX):])["counts"]


# --------------------------------------------------------------------------------------------
# (a) SIGKILL
# --------------------------------------------------------------------------------------------


def test_sigkill_keeps_every_message_up_to_the_last_flush(tmp_path):
    """Realtime loop at 50 frames/s, logger killed after about 3 s.

    What the file yields must be a contiguous prefix of what a subscriber of its own
    received on plant/state, and every message the plant sent more than one flush period
    (plus the receive skew) before the kill must be in it.
    """
    path, domain = tmp_path / "killed.mcap", fresh_domain_id()
    probe = RawProbe(domain, (contract.TOPIC_PMU, contract.TOPIC_PLANT_STATE))
    try:
        with node_processes(tmp_path, domain) as start:
            logger = start("logger", LOGGER, {"output_path": str(path), "discovery_period_s": 0.1})
            start("controller", CONTROLLER, {"battery_limit_pu": 0.3})
            start("plant", PLANT, {"mode": "realtime", "duration_s": 0.0, "wait_for_subscribers": 3})
            probe.wait_for(contract.TOPIC_PLANT_STATE, int(3.0 * RATE_HZ), timeout=30.0)
            kill_ns = time.time_ns()
            logger.kill()
            received = probe.take(contract.TOPIC_PLANT_STATE)
    finally:
        probe.close()
    assert len(received) >= 3.0 * RATE_HZ, "the loop ran for 3 s"
    assert not path.read_bytes().endswith(MCAP_MAGIC), "killed: the file has no footer"

    recorded = [r.cdr_bytes for r in read_messages(path) if r.topic == "/" + contract.TOPIC_PLANT_STATE]
    assert recorded == [cdr for _, cdr in received[: len(recorded)]], "a contiguous prefix, byte for byte"
    lost_times_s = [(kill_ns - t) * 1e-9 for t, _ in received[len(recorded):] if t < kill_ns]
    bound_s = FLUSH_PERIOD_S + RECEIVE_SKEW_S
    print(f"SIGKILL: {len(recorded)} plant states recovered, {len(lost_times_s)} lost "
          f"(sent {max(lost_times_s, default=0.0):.3f} s or less before the kill; bound {bound_s} s)")
    assert all(age_s <= bound_s for age_s in lost_times_s), lost_times_s
    assert len(lost_times_s) <= math.ceil(bound_s * RATE_HZ)
    # The recovered part is a usable recording, said to be partial: refused for the viewer unless
    # asked for, then converted with a warning that says how much it holds.
    refused = subprocess.run([str(NNI_REPLAY), str(path), "--rrd", str(tmp_path / "killed.rrd")],
                             capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2 and "incomplete recording" in refused.stderr, refused.stderr
    assert not (tmp_path / "killed.rrd").exists()
    view = subprocess.run([str(NNI_REPLAY), str(path), "--rrd", str(tmp_path / "killed.rrd"), "--allow-partial"],
                          capture_output=True, text=True, timeout=60)
    assert view.returncode == 0, view.stderr
    assert "incomplete recording" in view.stderr


# --------------------------------------------------------------------------------------------
# (b), (c) clean stop, namespaces
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def two_generators(tmp_path_factory) -> dict:
    """Plant + controller in /gen1 (b = 0.3) and /gen2 (b = inf), realtime for 2 s.

    Two loggers record them; after the plants end one is stopped with SIGINT, the other
    with SIGTERM. Returns signal -> (file, exit status, logger output).
    """
    tmp = tmp_path_factory.mktemp("namespaces")
    domain = fresh_domain_id()
    results = {}
    with node_processes(tmp, domain) as start:
        loggers = {
            signum: start(f"logger_{signum.name}", LOGGER,
                          {"output_path": str(tmp / f"{signum.name}.mcap"), "discovery_period_s": 0.1},
                          ros_args=("-r", f"__node:=logger_{signum.name.lower()}"))
            for signum in (signal.SIGINT, signal.SIGTERM)
        }
        plants = []
        for namespace, b in NAMESPACES.items():
            remap = ("-r", f"__ns:={namespace}")
            start(f"controller{namespace[1:]}", CONTROLLER, {"battery_limit_pu": b}, ros_args=remap)
            plants.append(start(f"plant{namespace[1:]}", PLANT,
                                {"mode": "realtime", "duration_s": 2.0, "wait_for_subscribers": 3}, ros_args=remap))
        for plant in plants:
            assert plant.wait(timeout=60) == 0, plant.output()
        # What each plant sent: realtime on a loaded machine it may skip reporting instants (it counts them; once
        # 16 of 100), and the logger is judged on what was sent.
        results["sent"] = {namespace: plant_summary(plant.output()) for namespace, plant in zip(NAMESPACES, plants)}
        time.sleep(0.5)  # the last reliable messages land
        for signum, logger in loggers.items():
            logger.proc.send_signal(signum)
            status = logger.proc.wait(timeout=15)
            results[signum] = (tmp / f"{signum.name}.mcap", status, logger.output())
    return results


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_finishes_the_file_and_counts_match(two_generators, signum):
    path, status, output = two_generators[signum]
    assert status == 0, output
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.chunk_indexes, "finished: summary and chunk indexes"
    assert path.read_bytes().endswith(MCAP_MAGIC)
    from_summary = {summary.channels[cid].topic: n for cid, n in summary.statistics.channel_message_counts.items()}
    counts = printed_counts(output)
    assert counts == file_counts(path) == from_summary
    for namespace, sent in two_generators["sent"].items():
        assert int(sent["measurements"]) + int(sent["skipped_reports"]) == 2.0 * RATE_HZ, sent
        assert counts[namespace + "/" + contract.TOPIC_PMU] == int(sent["measurements"]), namespace
        assert counts[namespace + "/" + contract.TOPIC_PLANT_STATE] == int(sent["measurements"]) + 1, namespace


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_one_logger_records_both_namespaces(two_generators, signum):
    path, _, _ = two_generators[signum]
    expected = {fully_qualified(topic, ns) for ns in NAMESPACES for topic in contract.TOPICS
                if topic not in ("/clock", contract.TOPIC_C37118_PMU)}
    assert set(file_counts(path)) == expected, \
        "every contract topic of both generators, no /clock (realtime), no c37118/pmu (measurements through ROS)"
    runs = read_generator_runs(path)
    assert list(runs) == list(NAMESPACES)
    for namespace, b in NAMESPACES.items():
        run = runs[namespace]
        assert run.battery_limit_pu == b
        assert run.stamp_ns.size == int(two_generators["sent"][namespace]["measurements"]) + 1, namespace
        assert run.omega_boundary is not None


def test_diagnostics_are_on_the_absolute_topic_and_name_their_generator(two_generators):
    path, _, _ = two_generators[signal.SIGINT]
    statuses = {(status.name, status.hardware_id)
                for record in read_messages(path) if record.topic == contract.TOPIC_DIAGNOSTICS
                for status in deserialize(record.type_name, record.cdr_bytes).status}
    assert statuses == {(f"{ns[1:]}/{node}", f"{ns}/{node}") for ns in NAMESPACES for node in ("plant", "controller")}
    for namespace, run in read_generator_runs(path).items():
        assert int(run.diagnostics["samples"]) >= 0.9 * 2.0 * RATE_HZ, namespace


# --------------------------------------------------------------------------------------------
# (d) replay
# --------------------------------------------------------------------------------------------


def test_replay_republishes_the_recording_unchanged():
    # Quarter speed: the lockstep recording bursts at ~700 samples/s per topic (2,500 messages in
    # 0.72 s); at half speed a loaded 2-core machine once fell 0.2 s behind over the playback (the
    # replay and the Python probe CPU-bound), at a quarter the probe keeps up and the bounds below
    # still judge the pacing.
    recording, rate = RECORDINGS / "paper_b0.3.mcap", 0.25
    expected = defaultdict(list)
    for record in read_messages(recording):
        expected[record.topic].append(record)
    domain = fresh_domain_id()
    probe = RawProbe(domain, tuple(contract.TOPICS))
    try:
        result = subprocess.run([str(NNI_REPLAY), str(recording), "--rate", str(rate), "--wait-for-subscribers", "1"],
                                env=ros_env(domain), capture_output=True, text=True, timeout=60)
        assert result.returncode == 0, result.stdout + result.stderr
        received = {topic: probe.wait_for(topic, len(expected[fully_qualified(topic)]), 5.0)
                    for topic in contract.TOPICS}
    finally:
        probe.close()
    for topic, messages in received.items():
        records = expected[fully_qualified(topic)]
        assert [cdr for _, cdr in messages] == [r.cdr_bytes for r in records], topic
    # Original spacing divided by the rate, as the replay sent them (source timestamps: the
    # probe's own delays under load do not count). Idle, each plant state goes out within ~10 ms
    # of its slot; a loaded 2-core machine delays single timer callbacks by 0.1 s, so the test
    # bounds the median deviation and the length of the whole playback. The deviation is taken
    # about its median, not about the first state: on a clean clone the first publish once went
    # out 66 ms late (a process's first message), which made every later one look early.
    states, records = received[contract.TOPIC_PLANT_STATE], expected["/" + contract.TOPIC_PLANT_STATE]
    arrival_s = np.array([t - states[0][0] for t, _ in states]) * 1e-9
    slot_s = np.array([r.log_time_ns - records[0].log_time_ns for r in records]) * 1e-9 / rate
    lateness_s = arrival_s - slot_s
    assert np.median(np.abs(lateness_s - np.median(lateness_s))) < 0.02
    assert arrival_s[-1] - arrival_s[1] == pytest.approx(slot_s[-1] - slot_s[1], rel=0.1)


#: The synthetic realtime recording below: plant states every 50 ms for 0.95 s, Omega latched at 0.
SYNTHETIC_PERIOD_NS = 50_000_000
SYNTHETIC_STATES = 20
SYNTHETIC_START_NS = 1_700_000_000 * 1_000_000_000


def write_realtime_recording(path: Path) -> list:
    """A small realtime-style recording (no /clock): returns its plant-state CDR bytes in order."""
    states = []
    with Ros2McapWriter(path) as writer:
        omega = writer.add_channel("/" + contract.TOPIC_INVARIANT_SET, contract.TOPICS[contract.TOPIC_INVARIANT_SET][0],
                                   qos_profiles_yaml([contract.LATCHED_QOS]))
        plant = writer.add_channel("/" + contract.TOPIC_PLANT_STATE, contract.TOPICS[contract.TOPIC_PLANT_STATE][0],
                                   qos_profiles_yaml([contract.SAMPLE_QOS]))
        boundary = [(-1.0, 0.0), (0.0, 1.0), (1.0, 0.0), (0.0, -1.0)]
        writer.write(omega, serialize_message(contract.invariant_set_message(SYNTHETIC_START_NS, boundary)),
                     SYNTHETIC_START_NS, SYNTHETIC_START_NS)
        for k in range(SYNTHETIC_STATES):
            stamp = SYNTHETIC_START_NS + k * SYNTHETIC_PERIOD_NS
            cdr = serialize_message(contract.plant_state_message(stamp, 0.9 + 0.01 * k, 0.1 * k, 0.0))
            writer.write(plant, cdr, stamp, stamp)
            states.append(cdr)
    return states


def test_replay_start_offset_sends_the_latched_state_then_the_rest_with_clock(tmp_path):
    """--start-offset 0.5 skips the first ten states at once, Omega (latched) still goes out first;
    --clock publishes the recording's time from the start point on."""
    path = tmp_path / "realtime.mcap"
    states = write_realtime_recording(path)
    offset_s = 0.5
    domain = fresh_domain_id()
    probe = RawProbe(domain, (contract.TOPIC_PLANT_STATE, contract.TOPIC_INVARIANT_SET, contract.TOPIC_CLOCK))
    try:
        result = subprocess.run([str(NNI_REPLAY), str(path), "--start-offset", str(offset_s), "--clock",
                                 "--wait-for-subscribers", "1"],
                                env=ros_env(domain), capture_output=True, text=True, timeout=60)
        assert result.returncode == 0, result.stdout + result.stderr
        skipped = round(offset_s * 1e9 / SYNTHETIC_PERIOD_NS)
        received = probe.wait_for(contract.TOPIC_PLANT_STATE, SYNTHETIC_STATES - skipped, 5.0)
        omega = probe.take(contract.TOPIC_INVARIANT_SET)
        clock = probe.take(contract.TOPIC_CLOCK)
    finally:
        probe.close()
    assert [cdr for _, cdr in received] == states[skipped:], "the states from the offset on, in order"
    assert len(omega) == 1, "the latched Omega recorded before the offset goes out once"
    # Published in the same timer callback as the first due state: no wait for the skipped part.
    assert (received[0][0] - omega[0][0]) * 1e-9 < 0.25
    # The rest (0.45 s of recording) keeps its spacing: a wait for the skipped 0.5 s would double it.
    assert 0.3 < (received[-1][0] - received[0][0]) * 1e-9 < 0.8
    clock_ns = [contract.ns_from_time(deserialize(contract.TOPICS[contract.TOPIC_CLOCK][0], cdr).clock)
                for _, cdr in clock]
    assert len(clock_ns) >= 5, "40 Hz over 0.45 s"
    assert clock_ns == sorted(clock_ns)
    start_ns = SYNTHETIC_START_NS + round(offset_s * 1e9)
    end_ns = SYNTHETIC_START_NS + (SYNTHETIC_STATES - 1) * SYNTHETIC_PERIOD_NS
    # The clock runs from the start point to the last message, plus at most one 25 ms tick.
    assert start_ns <= clock_ns[0] and clock_ns[-1] <= end_ns + 30_000_000, (clock_ns[0], clock_ns[-1])


def test_replay_loop_repeats_the_recording_until_interrupted(tmp_path):
    path = tmp_path / "realtime.mcap"
    states = write_realtime_recording(path)
    passes = 3
    domain = fresh_domain_id()
    probe = RawProbe(domain, (contract.TOPIC_PLANT_STATE, contract.TOPIC_INVARIANT_SET))
    try:
        replay = NodeProcess([str(NNI_REPLAY), str(path), "--loop", "--rate", "4", "--wait-for-subscribers", "1"],
                             ros_env(domain), tmp_path / "replay.log")
        received = probe.wait_for(contract.TOPIC_PLANT_STATE, passes * SYNTHETIC_STATES, 30.0)
        status = replay.interrupt(timeout=10.0)
        omega = probe.take(contract.TOPIC_INVARIANT_SET)
    finally:
        probe.close()
    assert status == 0, replay.output()
    assert len(received) >= passes * SYNTHETIC_STATES, replay.output()
    repeated = states * (len(received) // SYNTHETIC_STATES + 1)
    assert [cdr for _, cdr in received] == repeated[: len(received)], "whole passes, back to back, in order"
    assert len(omega) >= passes, "each pass starts with the recording's first message (Omega)"


@pytest.mark.parametrize("wait", [[], ["--wait-topic", "/plant/state"]], ids=["default", "wait_topic"])
def test_replay_waits_for_a_subscriber_of_one_topic(wait):
    """A lockstep recording at the default rate (about 1.2 s of playback): a subscriber of plant/state
    alone, started after the replay, on a machine with two busy processes, gets every state.

    Before: at the default (no wait) the replay had ended before the subscriber matched (checked:
    with --wait-for-subscribers 0 this test fails), and --wait-for-subscribers 1 waited for a
    subscriber on every topic, so this one hung it."""
    recording = RECORDINGS / "paper_b0.3.mcap"
    expected = [r.cdr_bytes for r in read_messages(recording) if r.topic == "/" + contract.TOPIC_PLANT_STATE]
    domain = fresh_domain_id()
    with busy_processes(2):
        replay = subprocess.Popen([str(NNI_REPLAY), str(recording), *wait], env=ros_env(domain),
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        time.sleep(1.0)
        probe = RawProbe(domain, (contract.TOPIC_PLANT_STATE,))
        try:
            output, _ = replay.communicate(timeout=60)
            received = probe.wait_for(contract.TOPIC_PLANT_STATE, len(expected), 10.0)
        finally:
            probe.close()
    assert replay.returncode == 0, output
    assert "waiting for 1 subscriber(s)" in output, "it says what it waits for"
    assert [cdr for _, cdr in received] == expected


# --------------------------------------------------------------------------------------------
# (f) a recording describes itself
# --------------------------------------------------------------------------------------------


def plant_parameters() -> dict:
    return dict(plant_defaults(), mode="lockstep", duration_s=10.0, wait_for_subscribers=2)


def controller_parameters(b: float) -> dict:
    return dict(controller_defaults(), battery_limit_pu=b)


@pytest.fixture(scope="module")
def described_run(tmp_path_factory) -> tuple[Path, dict]:
    """A lockstep run of the paper's case, b = 0.3, its logger given the run's parameters."""
    tmp = tmp_path_factory.mktemp("described")
    path = tmp / "run.mcap"
    metadata = {"scenario": {"name": "initial_angle", "delta0_rad": 0.2}, "plant": plant_parameters(),
                "controller": controller_parameters(0.3), "mode": "lockstep", "rate_hz": 50.0,
                "software_version": "test"}
    text = json.dumps(metadata)
    with node_processes(tmp, fresh_domain_id()) as start:
        # node_command passes strings YAML-quoted, so ROS takes the JSON object as the string parameter.
        logger = start("logger", LOGGER, {"output_path": str(path), "discovery_period_s": 0.1,
                                          "run_metadata": text})
        start("controller", CONTROLLER, {"battery_limit_pu": 0.3})
        plant = start("plant", PLANT, {"mode": "lockstep", "duration_s": 10.0, "wait_for_subscribers": 2})
        assert plant.wait(timeout=120) == 0, plant.output()
        time.sleep(0.5)
        assert logger.interrupt(timeout=15) == 0, logger.output()
    return path, json.loads(text)


def test_run_parameters_and_ros_distro_are_in_the_file(described_run):
    """Read with the mcap library (no code of ours): nni_run and rosbag2's metadata record."""
    path, metadata = described_run
    with path.open("rb") as stream:
        reader = make_reader(stream)
        records = {record.name: record.metadata for record in reader.iter_metadata()}
        statistics = reader.get_summary().statistics
    assert {key: json.loads(value) for key, value in records[RUN_METADATA_NAME].items()} == metadata
    rosbag2 = records["rosbag2"]
    assert rosbag2["ROS_DISTRO"] == "jazzy"
    bag = yaml.safe_load(rosbag2["serialized_metadata"])
    assert bag["ros_distro"] == "jazzy" and bag["version"] == 9 and bag["storage_identifier"] == "mcap"
    assert bag["message_count"] == statistics.message_count
    assert {t["topic_metadata"]["name"]: t["message_count"] for t in bag["topics_with_message_count"]} == \
        file_counts(path)


def test_info_prints_what_ros2_bag_info_shows_the_parameters_and_the_verdicts(described_run):
    path, metadata = described_run
    result = subprocess.run([str(NNI_REPLAY), str(path), "--info"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "ROS Distro:        jazzy" in out and "Complete:          yes" in out
    counts = file_counts(path)
    assert f"Messages:          {sum(counts.values())}" in out
    for topic, count in counts.items():
        assert f"Topic: {topic} | " in out and f"| Count: {count} |" in out.split(f"Topic: {topic} | ")[1].split("\n")[0]
    assert "QoS: reliable, volatile" in out and "QoS: reliable, transient_local" in out
    for key, value in metadata.items():
        assert f"  {key}: {json.dumps(value)}" in out
    verdicts = out.split("Verdicts:\n")[1].splitlines()
    printed = dict(line.strip().split(": ", 1) for line in verdicts if line.startswith("  "))
    assert set(printed) >= {field.name for field in dataclasses.fields(Outcome)}, "every key of to_json()"
    assert printed["b"] == "0.3" and printed["stable"] == "true", "the paper: b = 0.3 returns to equilibrium"


def test_plot_draws_the_run_and_rrd_takes_f0_from_the_recording(described_run, tmp_path):
    path, _ = described_run
    figure = tmp_path / "run.png"
    result = subprocess.run([str(NNI_REPLAY), str(path), "--plot", str(figure)], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and figure.stat().st_size > 10_000
    rrd = subprocess.run([str(NNI_REPLAY), str(path), "--rrd", str(tmp_path / "run.rrd")], capture_output=True,
                         text=True, timeout=60)
    assert rrd.returncode == 0 and "warning" not in rrd.stderr, rrd.stderr
    refused = subprocess.run([str(NNI_REPLAY), str(path), "--rrd", str(tmp_path / "other.rrd"), "--f0-hz", "60"],
                             capture_output=True, text=True, timeout=60)
    assert_one_line_error(refused, "nni-replay")
    assert "records f0 = 50 Hz" in refused.stderr


def without_metadata(source: Path, path: Path) -> Path:
    """A copy of ``source`` with every schema, channel and message but no metadata record (as recorded before
    the logger wrote ``nni_run``)."""
    with source.open("rb") as stream, path.open("wb") as out:
        reader, writer = make_reader(stream), Writer(out)
        writer.start(profile=reader.get_header().profile, library="test")
        schemas, channels = {}, {}
        for schema, channel, message in reader.iter_messages():
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding,
                                                               schemas[schema.id], channel.metadata)
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time,
                               message.sequence)
        writer.finish()
    return path


def test_a_recording_without_parameters_is_refused_for_what_needs_them(tmp_path):
    # The shipped recordings carry their parameters now (regenerated): this is one as they were before.
    shipped = without_metadata(RECORDINGS / "paper_b0.3.mcap", tmp_path / "old.mcap")
    plot = subprocess.run([str(NNI_REPLAY), str(shipped), "--plot", str(tmp_path / "x.png")], capture_output=True,
                          text=True, timeout=60)
    assert_one_line_error(plot, "nni-replay")
    assert "no run parameters" in plot.stderr and not (tmp_path / "x.png").exists()
    info = subprocess.run([str(NNI_REPLAY), str(shipped), "--info"], capture_output=True, text=True, timeout=60)
    assert info.returncode == 0 and "Run parameters:    not recorded" in info.stdout, info.stderr


# --------------------------------------------------------------------------------------------
# (e) bad input
# --------------------------------------------------------------------------------------------


def write_unknown_type(path: Path) -> None:
    """A ros2-profile MCAP whose only channel has a type no installed package defines."""
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema("nni_fake_msgs/msg/Nothing", "ros2msg", b"float64 x")
        channel = writer.register_channel("/plant/state", "cdr", schema, {"offered_qos_profiles": "[]"})
        writer.add_message(channel, log_time=1, publish_time=1, data=b"\x00\x01\x00\x00" + bytes(8))
        writer.finish()


def write_topics(path: Path, topics: dict) -> None:
    """A recording holding one /clock message on each ``topic: type`` (clock messages only)."""
    with Ros2McapWriter(path) as writer:
        for topic, type_name in topics.items():
            channel = writer.add_channel(topic, type_name, qos_profiles_yaml([]))
            writer.write(channel, serialize_message(Clock()), 1, 1)


def make_bad_input(kind: str, folder: Path) -> Path:
    good = (RECORDINGS / "paper_b0.3.mcap").read_bytes()
    path = folder / f"{kind}.mcap"
    if kind == "missing":
        return path
    if kind == "not_mcap":
        path.write_text("time,angle\n0,0.2\n")
    elif kind == "cut_in_header":
        path.write_bytes(good[:20])
    elif kind == "cut_before_first_flush":
        path.write_bytes(good[:200])  # header whole, first chunk cut
    elif kind == "no_plant_state":
        write_topics(path, {"/clock": "rosgraph_msgs/msg/Clock"})
    elif kind == "wrong_type_on_contract_topic":
        write_topics(path, {"/plant/state": "rosgraph_msgs/msg/Clock"})
    elif kind == "unknown_type":
        write_unknown_type(path)
    return path


def assert_one_line_error(result: subprocess.CompletedProcess, prog: str) -> None:
    lines = result.stderr.strip().splitlines()
    assert result.returncode != 0
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: "), result.stderr
    assert "Traceback" not in result.stdout + result.stderr


BAD_INPUTS = ["missing", "not_mcap", "cut_in_header", "cut_before_first_flush", "no_plant_state",
              "wrong_type_on_contract_topic", "unknown_type"]


@pytest.mark.parametrize("kind", BAD_INPUTS)
def test_replay_rejects_bad_input_to_rrd(tmp_path, kind):
    source, out = tmp_path / "in", tmp_path / "out"
    source.mkdir()
    out.mkdir()
    result = subprocess.run([str(NNI_REPLAY), str(make_bad_input(kind, source)), "--rrd", str(out / "view.rrd")],
                            capture_output=True, text=True, timeout=60)
    assert_one_line_error(result, "nni-replay")
    assert list(out.iterdir()) == [], "no output file, whole or partial"


@pytest.mark.parametrize("kind", ["missing", "no_plant_state", "unknown_type"])
def test_replay_rejects_bad_input_before_starting_ros(tmp_path, kind):
    result = subprocess.run([str(NNI_REPLAY), str(make_bad_input(kind, tmp_path))],
                            env=ros_env(fresh_domain_id()), capture_output=True, text=True, timeout=60)
    assert_one_line_error(result, "nni-replay")


BAD_USAGE = {
    "offset_past_the_end": ["--start-offset", "100"],
    "clock_on_a_lockstep_recording": ["--clock"],
    "zero_rate": ["--rate", "0"],
    "ros_option_with_rrd": ["--rrd", "{tmp}/view.rrd", "--loop"],
    "connect_url_not_rerun": ["--connect", "http://127.0.0.1:9876/proxy"],
    "connect_nobody_listening": ["--connect", "{closed_port}"],
    "spawn_without_display": ["--spawn"],
}


def closed_port() -> int:
    """A TCP port on localhost with nobody listening (bound, then released)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.mark.parametrize("kind", BAD_USAGE)
def test_replay_rejects_bad_usage(tmp_path, kind):
    args = [arg.format(tmp=tmp_path, closed_port=closed_port()) for arg in BAD_USAGE[kind]]
    env = {name: value for name, value in ros_env(fresh_domain_id()).items()
           if name not in ("DISPLAY", "WAYLAND_DISPLAY")}
    started = time.monotonic()
    result = subprocess.run([str(NNI_REPLAY), str(RECORDINGS / "paper_b0.3.mcap"), *args],
                            env=env, capture_output=True, text=True, timeout=60)
    assert_one_line_error(result, "nni-replay")
    assert list(tmp_path.iterdir()) == []
    assert time.monotonic() - started < 15, "refused at once, not after a replay or a connection retry loop"


def stamp_of(msg) -> int:
    """A message's header stamp, ns."""
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def test_publish_time_is_the_senders_dds_source_timestamp(tmp_path):
    """As rosbag2 records it: publish_time = the DDS source timestamp (the writer's clock), log_time = receive time.

    The probe publishes PMU messages whose header stamps are far in the past (1970 + k s) and reads
    each sample's source timestamp from its own subscription's message info (DDS gives every reader
    of a sample the same one). A logger that wrote its receive time, or the header stamp, fails the
    equality; the receive time comes after the send.
    """
    domain, path = fresh_domain_id(), tmp_path / "sent.mcap"
    sent: dict[int, int] = {}  # header stamp -> source timestamp seen by the probe
    with node_processes(tmp_path, domain) as start:
        logger = start("logger", LOGGER, {"output_path": str(path), "discovery_period_s": 0.1})
        probe = Probe(domain, ())
        try:
            msg_class, name, qos = contract.recorder_endpoint(contract.TOPIC_PMU)
            probe.node.create_subscription(
                msg_class, name, lambda msg, info: sent.__setitem__(stamp_of(msg),
                                                                    info["source_timestamp"]), qos)
            assert probe.wait_matched(contract.TOPIC_PMU, 2, 30.0), "the probe's own reader and the logger's"
            for k in range(1, 21):
                probe.publish(contract.TOPIC_PMU, sealed_pmu(contract.pmu_message(k * 1_000_000_000, 0.1 * k, 0.0, 0.5)))
                time.sleep(0.02)
            time.sleep(0.5)
        finally:
            probe.close()
        assert logger.interrupt(timeout=15) == 0, logger.output()
    recorded = [record for record in read_messages(path) if record.topic == "/" + contract.TOPIC_PMU]
    assert len(recorded) == len(sent) == 20
    for record in recorded:
        stamp = stamp_of(deserialize(record.type_name, record.cdr_bytes))
        assert record.publish_time_ns == sent[stamp], "the sender's DDS source timestamp"
        assert record.publish_time_ns != stamp and record.publish_time_ns < record.log_time_ns
        assert record.log_time_ns - record.publish_time_ns < 5e9


def test_logger_rejects_a_missing_output_folder(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", LOGGER, "--ros-args", "-p", f"output_path:={tmp_path / 'absent' / 'run.mcap'}"],
        env=ros_env(fresh_domain_id()), capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert_one_line_error(result, "mcap_logger")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("text", ["'not json'", "'[1, 2]'"], ids=["not_json", "not_an_object"])
def test_logger_rejects_run_metadata_that_is_not_a_json_object(tmp_path, text):
    result = subprocess.run(
        [sys.executable, "-m", LOGGER, "--ros-args", "-p", f"output_path:={tmp_path / 'run.mcap'}",
         "-p", f"run_metadata:={text}"],
        env=ros_env(fresh_domain_id()), capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert_one_line_error(result, "mcap_logger")
    assert "run_metadata" in result.stderr
    assert list(tmp_path.iterdir()) == []


def test_the_four_paper_replays_merged_show_four_runs(tmp_path):
    """Issue 10: `rerun rrd merge` of the four replays showed one run. One recording with the four now."""
    from rerun.chunk import RrdReader

    paths = []
    for name in ("paper_b0", "paper_b0.2", "paper_b0.3", "paper_binf"):
        out = tmp_path / f"{name}.rrd"
        result = subprocess.run([str(NNI_REPLAY), str(RECORDINGS / f"{name}.mcap"), "--rrd", str(out)],
                                capture_output=True, text=True, timeout=120)
        assert result.returncode == 0, result.stderr
        paths.append(out)
    merged = tmp_path / "merged.rrd"
    rerun_cli = Path(sys.executable).parent / "rerun"
    result = subprocess.run([str(rerun_cli), "rrd", "merge", *map(str, paths), "-o", str(merged)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    reader = RrdReader(merged)
    assert len(reader.recordings()) == 1
    entities = {chunk.entity_path for chunk in reader.stream()}
    # Entity paths escape '=': the angle deviation of each run, one series per b in the same view.
    assert {f"/angle_deviation/b\\={b}" for b in ("0", "0.2", "0.3", "inf")} <= entities, sorted(entities)
