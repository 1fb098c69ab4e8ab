"""Tests of nni_msgs_adapter.recording.mcap_io against independent readers and killed recorders.

Files are written with real ROS messages (rclpy serialization, no DDS) and checked with
rosbags (reads rosbag2 MCAP, deserializes CDR from the embedded definitions), mcap-ros2-support
(decodes CDR from the schema text), and ``rerun mcap check``. Killed recordings are simulated by
copying prefixes of a file written with several flushes, and once by SIGKILL.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import pytest
import yaml
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point32, PolygonStamped
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import SeekingReader, make_reader
from mcap.writer import Writer
from mcap_ros2.decoder import DecoderFactory
from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosDurability, QosHistory, QosReliability
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from nni_msgs_adapter.recording.mcap_io import (
    MCAP_MAGIC,
    OfferedQos,
    RecordedMessage,
    RecordingError,
    Ros2McapWriter,
    deserialize,
    message_class,
    message_definition,
    parse_qos_profiles_yaml,
    qos_profiles_yaml,
    read_messages,
)

VENV_BIN = Path(sys.executable).parent
RERUN_CLI = VENV_BIN / "rerun"
SHARE = Path(sys.prefix) / "share"
T0_NS = 1_700_000_000_000_000_000
MESSAGE_SPACING_NS = 1_000_000
PUBLISH_LEAD_NS = 100_000
NO_TIMER_FLUSH_S = 3600.0


@dataclass(frozen=True)
class TopicSpec:
    """A recorded topic: name, full type, offered QoS and a message factory (round -> msg)."""

    topic: str
    type_name: str
    qos: QoSProfile
    make: Callable[[int], Any]


def stamp(round_index: int) -> Time:
    """A header stamp that advances 20 ms per round."""
    return Time(sec=1_700_000_000 + round_index // 50, nanosec=(round_index % 50) * 20_000_000)


def joint_state(round_index: int) -> JointState:
    message = JointState(
        name=["rotor"],
        position=[0.2 + 0.01 * round_index],
        velocity=[-0.5 * round_index],
        effort=[0.8],
    )
    message.header.stamp = stamp(round_index)
    message.header.frame_id = "gen1"
    return message


def diagnostic_array(round_index: int) -> DiagnosticArray:
    status = DiagnosticStatus(
        level=DiagnosticStatus.WARN if round_index % 2 else DiagnosticStatus.OK,
        name="battery",
        message=f"round {round_index}",
        hardware_id="inverter-1",
        values=[KeyValue(key="saturated", value=str(round_index % 2 == 1))],
    )
    message = DiagnosticArray(status=[status])
    message.header.stamp = stamp(round_index)
    return message


def polygon_stamped(round_index: int) -> PolygonStamped:
    message = PolygonStamped()
    message.header.stamp = stamp(round_index)
    message.header.frame_id = "phase_plane"
    message.polygon.points = [
        Point32(x=float(k), y=0.5 * k + round_index, z=-1.0) for k in range(3)
    ]
    return message


def clock(round_index: int) -> Clock:
    return Clock(clock=stamp(round_index))


TOPICS = (
    TopicSpec(
        "/gen1/pmu",
        "sensor_msgs/msg/JointState",
        QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT),
        joint_state,
    ),
    TopicSpec(
        "/gen1/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", QoSProfile(depth=10), diagnostic_array
    ),
    TopicSpec(
        "/gen1/invariant_set",
        "geometry_msgs/msg/PolygonStamped",
        QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL),
        polygon_stamped,
    ),
    TopicSpec(
        "/clock",
        "rosgraph_msgs/msg/Clock",
        QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT),
        clock,
    ),
)
TOPICS_BY_NAME = {spec.topic: spec for spec in TOPICS}


@dataclass(frozen=True)
class WrittenMessage:
    topic: str
    message: Any
    log_time_ns: int
    publish_time_ns: int
    cdr_bytes: bytes


@dataclass(frozen=True)
class Flush:
    """State of the file right after an explicit flush."""

    file_size: int
    messages_written: int


def write_recording(
    path: Path, rounds: int, *, flush_each_round: bool = False
) -> tuple[list[WrittenMessage], list[Flush]]:
    """Write *rounds* rounds of one message per topic; return what was written and the flushes."""
    written: list[WrittenMessage] = []
    flushes: list[Flush] = []
    with Ros2McapWriter(path, flush_period_s=NO_TIMER_FLUSH_S) as writer:
        channels = {
            spec.topic: writer.add_channel(spec.topic, spec.type_name, qos_profiles_yaml([spec.qos]))
            for spec in TOPICS
        }
        for round_index in range(rounds):
            for spec in TOPICS:
                message = spec.make(round_index)
                log_time_ns = T0_NS + len(written) * MESSAGE_SPACING_NS
                cdr_bytes = serialize_message(message)
                entry = WrittenMessage(
                    spec.topic, message, log_time_ns, log_time_ns - PUBLISH_LEAD_NS, cdr_bytes
                )
                writer.write(channels[spec.topic], cdr_bytes, entry.log_time_ns, entry.publish_time_ns)
                written.append(entry)
            if flush_each_round:
                writer.flush()
                flushes.append(Flush(path.stat().st_size, len(written)))
        assert writer.counts == {spec.topic: rounds for spec in TOPICS}
    return written, flushes


def as_tuple(message: WrittenMessage | RecordedMessage) -> tuple[str, int, int, bytes]:
    return (message.topic, message.log_time_ns, message.publish_time_ns, message.cdr_bytes)


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[WrittenMessage]]:
    """A finished recording of all sample topics (one flush at close)."""
    path = tmp_path_factory.mktemp("recording") / "sample.mcap"
    written, _ = write_recording(path, rounds=12)
    return path, written


# ---------------------------------------------------------------------------------------------
# Schemas
# ---------------------------------------------------------------------------------------------


def msg_file_text(package: str, name: str) -> str:
    with (SHARE / package / "msg" / f"{name}.msg").open(encoding="utf-8", newline="") as msg_file:
        return msg_file.read()


def test_definition_concatenates_dependency_as_rosbag2_does() -> None:
    separator = "=" * 80
    expected = (
        msg_file_text("rosgraph_msgs", "Clock")
        + f"\n{separator}\nMSG: builtin_interfaces/Time\n"
        + msg_file_text("builtin_interfaces", "Time")
    )
    assert message_definition("rosgraph_msgs/msg/Clock") == expected


@pytest.mark.parametrize(
    ("type_name", "dependencies"),
    [
        ("sensor_msgs/msg/JointState", ["std_msgs/Header", "builtin_interfaces/Time"]),
        (
            "diagnostic_msgs/msg/DiagnosticArray",
            [
                "diagnostic_msgs/DiagnosticStatus",
                "diagnostic_msgs/KeyValue",
                "std_msgs/Header",
                "builtin_interfaces/Time",
            ],
        ),
        (
            "geometry_msgs/msg/PolygonStamped",
            [
                "geometry_msgs/Polygon",
                "geometry_msgs/Point32",
                "std_msgs/Header",
                "builtin_interfaces/Time",
            ],
        ),
    ],
)
def test_definition_lists_each_dependency_once_depth_first_in_sorted_order(
    type_name: str, dependencies: list[str]
) -> None:
    definition = message_definition(type_name)
    package, _, name = type_name.split("/")
    assert definition.startswith(msg_file_text(package, name))
    headers = [line for line in definition.splitlines() if line.startswith("MSG: ")]
    assert headers == [f"MSG: {dependency}" for dependency in dependencies]
    assert definition.count("=" * 80 + "\n") == len(dependencies)


def test_definition_matches_rosbag2_test_vector_through_ament_prefix_path(tmp_path: Path) -> None:
    """rosbag2's own test case (rosbag2_test_msgdefs/ComplexMsg), found via AMENT_PREFIX_PATH."""
    prefix = tmp_path / "install"
    package_index = prefix / "share" / "ament_index" / "resource_index" / "packages"
    package_index.mkdir(parents=True)
    (package_index / "rosbag2_test_msgdefs").write_text("")
    msg_dir = prefix / "share" / "rosbag2_test_msgdefs" / "msg"
    msg_dir.mkdir(parents=True)
    (msg_dir / "ComplexMsg.msg").write_text("rosbag2_test_msgdefs/BasicMsg b\n")
    (msg_dir / "BasicMsg.msg").write_text("float32 c\n")
    script = (
        "import json, sys\n"
        "from nni_msgs_adapter.recording.mcap_io import message_definition\n"
        "print(json.dumps([message_definition(name) for name in sys.argv[1:]]))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", script, "rosbag2_test_msgdefs/ComplexMsg", "sensor_msgs/msg/JointState"],
        env={**os.environ, "AMENT_PREFIX_PATH": f"{prefix}{os.pathsep}{sys.prefix}"},
        capture_output=True,
        text=True,
        check=True,
    )
    complex_definition, joint_state_definition = json.loads(result.stdout)
    assert complex_definition == (
        "rosbag2_test_msgdefs/BasicMsg b\n"
        "\n"
        "================================================================================\n"
        "MSG: rosbag2_test_msgdefs/BasicMsg\n"
        "float32 c\n"
    )
    assert joint_state_definition == message_definition("sensor_msgs/msg/JointState")


def test_schema_and_channel_records_follow_rosbag2(recording: tuple[Path, list[WrittenMessage]]) -> None:
    path, _ = recording
    with path.open("rb") as stream:
        reader = make_reader(stream)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == 12 * len(TOPICS)
    assert summary.chunk_indexes and all(index.message_index_offsets for index in summary.chunk_indexes)
    schemas = {schema.name: schema for schema in summary.schemas.values()}
    assert set(schemas) == {spec.type_name for spec in TOPICS}
    for channel in summary.channels.values():
        spec = TOPICS_BY_NAME[channel.topic]
        schema = summary.schemas[channel.schema_id]
        assert (schema.name, schema.encoding, channel.message_encoding) == (
            spec.type_name,
            "ros2msg",
            "cdr",
        )
        assert schema.data.decode() == message_definition(spec.type_name)
        assert channel.metadata["offered_qos_profiles"] == qos_profiles_yaml([spec.qos])
        assert channel.metadata["topic_type_hash"].startswith("RIHS01_")


# ---------------------------------------------------------------------------------------------
# (a) independent readers, (b) rerun
# ---------------------------------------------------------------------------------------------


def assert_same_fields(topic: str, decoded: Any, original: Any) -> None:
    """Compare a message decoded by another library with the rclpy message that was written."""
    if topic != "/clock":
        assert decoded.header.stamp.sec == original.header.stamp.sec
        assert decoded.header.stamp.nanosec == original.header.stamp.nanosec
        assert decoded.header.frame_id == original.header.frame_id
    if topic == "/gen1/pmu":
        assert list(decoded.name) == list(original.name)
        for field in ("position", "velocity", "effort"):
            assert list(getattr(decoded, field)) == list(getattr(original, field))
    elif topic == "/gen1/diagnostics":
        [status], [expected] = decoded.status, original.status
        assert (status.level, status.name, status.message, status.hardware_id) == (
            int.from_bytes(expected.level),
            expected.name,
            expected.message,
            expected.hardware_id,
        )
        assert [(kv.key, kv.value) for kv in status.values] == [
            (kv.key, kv.value) for kv in expected.values
        ]
    elif topic == "/gen1/invariant_set":
        assert [(p.x, p.y, p.z) for p in decoded.polygon.points] == [
            (p.x, p.y, p.z) for p in original.polygon.points
        ]
    else:
        assert (decoded.clock.sec, decoded.clock.nanosec) == (
            original.clock.sec,
            original.clock.nanosec,
        )


def test_rosbags_reads_bare_mcap_file(recording: tuple[Path, list[WrittenMessage]]) -> None:
    path, written = recording
    with AnyReader([path]) as reader:
        assert {(c.topic, c.msgtype) for c in reader.connections} == {
            (spec.topic, spec.type_name) for spec in TOPICS
        }
        read_back = [
            (connection.topic, timestamp, reader.deserialize(raw, connection.msgtype))
            for connection, timestamp, raw in reader.messages()
        ]
        qos_by_topic = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert [(topic, ts) for topic, ts, _ in read_back] == [(w.topic, w.log_time_ns) for w in written]
    for (topic, _, decoded), original in zip(read_back, written):
        assert_same_fields(topic, decoded, original.message)
    [pmu_qos] = qos_by_topic["/gen1/pmu"]
    assert (pmu_qos.history, pmu_qos.depth, pmu_qos.reliability) == (
        QosHistory.KEEP_LAST,
        5,
        QosReliability.BEST_EFFORT,
    )
    [latched_qos] = qos_by_topic["/gen1/invariant_set"]
    assert latched_qos.durability == QosDurability.TRANSIENT_LOCAL


def test_mcap_ros2_decodes_with_embedded_schemas(recording: tuple[Path, list[WrittenMessage]]) -> None:
    path, written = recording
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        decoded = [
            (channel.topic, message.log_time, ros_message)
            for _, channel, message, ros_message in reader.iter_decoded_messages()
        ]
    assert [(topic, ts) for topic, ts, _ in decoded] == [(w.topic, w.log_time_ns) for w in written]
    for (topic, _, ros_message), original in zip(decoded, written):
        assert_same_fields(topic, ros_message, original.message)


@pytest.mark.parametrize("full", [False, True], ids=["structure", "decoded"])
def test_rerun_mcap_check_passes(recording: tuple[Path, list[WrittenMessage]], full: bool) -> None:
    path, _ = recording
    command = [str(RERUN_CLI), "mcap", "check", *(["--full"] if full else []), str(path)]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    # `rerun mcap check` exits 0 even when it reports problems; they appear as PROBLEM rows.
    assert "PROBLEM" not in result.stdout, result.stdout
    for spec in TOPICS:
        assert spec.topic in result.stdout


def test_read_messages_round_trips_through_rclpy(recording: tuple[Path, list[WrittenMessage]]) -> None:
    path, written = recording
    recorded = list(read_messages(path))
    assert [as_tuple(r) for r in recorded] == [as_tuple(w) for w in written]
    for record, original in zip(recorded, written):
        spec = TOPICS_BY_NAME[record.topic]
        assert record.type_name == spec.type_name
        assert parse_qos_profiles_yaml(record.qos_yaml) == [OfferedQos.from_rclpy(spec.qos)]
        assert deserialize(record.type_name, record.cdr_bytes) == original.message


def test_read_messages_sorts_finished_file_by_log_time(tmp_path: Path) -> None:
    path = tmp_path / "unordered.mcap"
    log_times = [T0_NS + offset for offset in (30, 10, 20)]
    with Ros2McapWriter(path) as writer:
        channel = writer.add_channel("/clock", "rosgraph_msgs/msg/Clock", qos_profiles_yaml([]))
        for log_time in log_times:
            writer.write(channel, serialize_message(Clock()), log_time, log_time)
    assert [r.log_time_ns for r in read_messages(path)] == sorted(log_times)


# ---------------------------------------------------------------------------------------------
# (c) QoS metadata
# ---------------------------------------------------------------------------------------------


def test_qos_yaml_is_rosbag2_jazzy_text() -> None:
    profile = QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
        deadline=Duration(seconds=1, nanoseconds=500_000_000),
        liveliness=LivelinessPolicy.AUTOMATIC,
    )
    assert qos_profiles_yaml([profile, OfferedQos(reliability=2)]) == (
        "- history: keep_last\n"
        "  depth: 1\n"
        "  reliability: reliable\n"
        "  durability: transient_local\n"
        "  deadline:\n"
        "    sec: 1\n"
        "    nsec: 500000000\n"
        "  lifespan:\n"
        "    sec: 0\n"
        "    nsec: 0\n"
        "  liveliness: automatic\n"
        "  liveliness_lease_duration:\n"
        "    sec: 0\n"
        "    nsec: 0\n"
        "  avoid_ros_namespace_conventions: false\n"
        "- history: keep_last\n"
        "  depth: 10\n"
        "  reliability: best_effort\n"
        "  durability: volatile\n"
        "  deadline:\n"
        "    sec: 0\n"
        "    nsec: 0\n"
        "  lifespan:\n"
        "    sec: 0\n"
        "    nsec: 0\n"
        "  liveliness: system_default\n"
        "  liveliness_lease_duration:\n"
        "    sec: 0\n"
        "    nsec: 0\n"
        "  avoid_ros_namespace_conventions: false"
    )
    assert qos_profiles_yaml([]) == "[]"


def policies(enum: type) -> st.SearchStrategy[int]:
    return st.sampled_from([int(member) for member in enum])


durations_ns = st.integers(min_value=0, max_value=2**63 - 1)
offered_qos = st.builds(
    OfferedQos,
    history=policies(HistoryPolicy),
    depth=st.integers(min_value=0, max_value=2**31),
    reliability=policies(ReliabilityPolicy),
    durability=policies(DurabilityPolicy),
    deadline_ns=durations_ns,
    lifespan_ns=durations_ns,
    liveliness=policies(LivelinessPolicy),
    liveliness_lease_duration_ns=durations_ns,
    avoid_ros_namespace_conventions=st.booleans(),
)


@given(profiles=st.lists(offered_qos, max_size=3))
def test_qos_yaml_parses_back_to_the_same_profiles(profiles: list[OfferedQos]) -> None:
    text = qos_profiles_yaml(profiles)
    assert parse_qos_profiles_yaml(text) == profiles
    # Any YAML parser reads it: policies as rmw names, durations as sec/nsec maps.
    for entry, profile in zip(yaml.safe_load(text) or [], profiles):
        assert entry["deadline"] == {
            "sec": profile.deadline_ns // 10**9,
            "nsec": profile.deadline_ns % 10**9,
        }


@given(profile=offered_qos.filter(lambda q: q.history != int(HistoryPolicy.UNKNOWN) and q.depth))
def test_offered_qos_round_trips_through_rclpy(profile: OfferedQos) -> None:
    assert OfferedQos.from_rclpy(profile.to_rclpy()) == profile


def test_qos_parser_accepts_integer_policies_of_older_rosbag2() -> None:
    humble_text = (
        "- history: 1\n  depth: 5\n  reliability: 2\n  durability: 1\n"
        "  deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 0\n    nsec: 0\n"
        "  liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n"
        "  avoid_ros_namespace_conventions: false"
    )
    assert parse_qos_profiles_yaml(humble_text) == [
        OfferedQos(history=1, depth=5, reliability=2, durability=1, liveliness=1)
    ]
    assert parse_qos_profiles_yaml("") == []


# ---------------------------------------------------------------------------------------------
# (d) killed recorders
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FlushedRecording:
    """A finished file written with one explicit flush (one chunk) per round."""

    data: bytes
    written: list[WrittenMessage]
    flushes: list[Flush]
    chunk_ends: list[int]  # file offset just past each chunk record, in file order


@pytest.fixture(scope="module")
def flushed_recording(tmp_path_factory: pytest.TempPathFactory) -> FlushedRecording:
    path = tmp_path_factory.mktemp("flushed") / "flushed.mcap"
    written, flushes = write_recording(path, rounds=6, flush_each_round=True)
    with path.open("rb") as stream:
        summary = SeekingReader(stream).get_summary()
    assert summary is not None
    chunk_ends = sorted(i.chunk_start_offset + i.chunk_length for i in summary.chunk_indexes)
    assert len(chunk_ends) == len(flushes)
    return FlushedRecording(path.read_bytes(), written, flushes, chunk_ends)


def check_prefix_recovery(recording: FlushedRecording, cut: int, directory: Path) -> None:
    """Read the first *cut* bytes as a killed recorder would have left them."""
    prefix_path = directory / "killed.mcap"
    prefix_path.write_bytes(recording.data[:cut])
    complete_chunks = sum(end <= cut for end in recording.chunk_ends)
    expected = recording.flushes[complete_chunks - 1].messages_written if complete_chunks else 0
    guaranteed = max((f.messages_written for f in recording.flushes if f.file_size <= cut), default=0)
    assert expected >= guaranteed
    if expected == 0:
        with pytest.raises(RecordingError, match="before its first flush|truncated|empty"):
            list(read_messages(prefix_path))
        return
    recovered = [as_tuple(r) for r in read_messages(prefix_path)]
    assert recovered == [as_tuple(w) for w in recording.written[:expected]]


@pytest.fixture(scope="module")
def cut_directory(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("cuts")


def test_cuts_at_flush_and_chunk_boundaries(
    flushed_recording: FlushedRecording, cut_directory: Path
) -> None:
    boundaries = {len(flushed_recording.data)}
    boundaries.update(f.file_size for f in flushed_recording.flushes)
    for end in flushed_recording.chunk_ends:
        boundaries.update({end - 1, end, end + 1})
    for cut in sorted(boundaries):
        check_prefix_recovery(flushed_recording, cut, cut_directory)


@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_cut_at_any_offset_yields_exactly_the_complete_chunks(
    flushed_recording: FlushedRecording, cut_directory: Path, data: st.DataObject
) -> None:
    cut = data.draw(st.integers(min_value=0, max_value=len(flushed_recording.data)), label="cut")
    check_prefix_recovery(flushed_recording, cut, cut_directory)


def test_rerun_recovers_the_same_cut_file(
    flushed_recording: FlushedRecording, cut_directory: Path
) -> None:
    cut = flushed_recording.chunk_ends[-1] - 1  # inside the last chunk
    path = cut_directory / "rerun_recover.mcap"
    path.write_bytes(flushed_recording.data[:cut])
    result = subprocess.run(
        [str(RERUN_CLI), "mcap", "check", "--recover", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert "truncated" in result.stderr
    chunks_per_topic = len(flushed_recording.chunk_ends) - 1
    for spec in TOPICS:
        [row] = [line.split() for line in result.stdout.splitlines() if spec.topic in line.split()]
        assert row[0] == "ok" and int(row[2]) == chunks_per_topic


def test_timer_flushes_while_writer_stays_open(tmp_path: Path) -> None:
    path = tmp_path / "open.mcap"
    snapshot = tmp_path / "snapshot.mcap"
    cdr_bytes = serialize_message(clock(1))
    with Ros2McapWriter(path, flush_period_s=0.05) as writer:
        channel = writer.add_channel("/clock", "rosgraph_msgs/msg/Clock", qos_profiles_yaml([]))
        for index in range(3):
            writer.write(channel, cdr_bytes, T0_NS + index, T0_NS + index)
        deadline = time.monotonic() + 10.0
        recovered: list[RecordedMessage] = []
        while len(recovered) < 3 and time.monotonic() < deadline:
            time.sleep(0.05)
            snapshot.write_bytes(path.read_bytes())
            try:
                recovered = list(read_messages(snapshot))
            except RecordingError:
                recovered = []
    assert [r.log_time_ns for r in recovered] == [T0_NS, T0_NS + 1, T0_NS + 2]


KILLED_RECORDER = """
import sys, time
from nni_msgs_adapter.recording.mcap_io import Ros2McapWriter, qos_profiles_yaml

path, cdr_bytes, count = sys.argv[1], bytes.fromhex(sys.argv[2]), int(sys.argv[3])
writer = Ros2McapWriter(path, flush_period_s=0.05)
channel = writer.add_channel("/clock", "rosgraph_msgs/msg/Clock", qos_profiles_yaml([]))
for index in range(count):
    writer.write(channel, cdr_bytes, index, index)
print("rclpy imported" if "rclpy" in sys.modules else "written", flush=True)
time.sleep(60)
"""


def test_sigkilled_recorder_leaves_a_readable_file(tmp_path: Path) -> None:
    path = tmp_path / "sigkilled.mcap"
    cdr_bytes = serialize_message(clock(7))
    recorder = subprocess.Popen(
        [sys.executable, "-c", KILLED_RECORDER, str(path), cdr_bytes.hex(), "40"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert recorder.stdout is not None
        assert recorder.stdout.readline().strip() == "written"  # and no rclpy import
        time.sleep(0.5)  # ten flush periods
    finally:
        recorder.send_signal(signal.SIGKILL)
        recorder.wait(timeout=10)
        if recorder.stdout is not None:
            recorder.stdout.close()
    assert recorder.returncode == -signal.SIGKILL
    assert not path.read_bytes().endswith(MCAP_MAGIC)  # no footer: the kill left it unfinished
    recovered = list(read_messages(path))
    assert [r.log_time_ns for r in recovered] == list(range(40))
    assert all(deserialize(r.type_name, r.cdr_bytes) == clock(7) for r in recovered)


# ---------------------------------------------------------------------------------------------
# Writer contract
# ---------------------------------------------------------------------------------------------


def test_writer_channel_rules(tmp_path: Path) -> None:
    writer = Ros2McapWriter(tmp_path / "rules.mcap")
    qos_yaml = qos_profiles_yaml([OfferedQos()])
    channel = writer.add_channel("/clock", "rosgraph_msgs/msg/Clock", qos_yaml)
    assert writer.add_channel("/clock", "rosgraph_msgs/msg/Clock", qos_yaml) == channel
    with pytest.raises(ValueError, match="already recorded as rosgraph_msgs/msg/Clock"):
        writer.add_channel("/clock", "sensor_msgs/msg/JointState", qos_yaml)
    with pytest.raises(RecordingError, match="not a full name"):
        writer.add_channel("/pmu", "sensor_msgs/JointState", qos_yaml)
    with pytest.raises(RecordingError, match="unknown message type 'sensor_msgs/msg/Rotor'"):
        writer.add_channel("/pmu", "sensor_msgs/msg/Rotor", qos_yaml)
    with pytest.raises(ValueError, match="no channel with id 99"):
        writer.write(99, b"", 0, 0)
    writer.close()
    writer.close()
    with pytest.raises(ValueError, match="is closed"):
        writer.write(channel, serialize_message(Clock()), 0, 0)
    assert writer.counts == {"/clock": 0}


# ---------------------------------------------------------------------------------------------
# (e) bad input
# ---------------------------------------------------------------------------------------------


def write_raw_mcap(path: Path, *, profile: str, schema: bool, message_encoding: str) -> None:
    """An MCAP file made with the plain mcap writer, to break one ros2 rule at a time."""
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start(profile=profile)
        schema_id = (
            writer.register_schema(
                "rosgraph_msgs/msg/Clock",
                "ros2msg",
                message_definition("rosgraph_msgs/msg/Clock").encode(),
            )
            if schema
            else 0
        )
        channel = writer.register_channel("/clock", message_encoding, schema_id)
        writer.add_message(channel, 0, serialize_message(Clock()), 0)
        writer.finish()


def valid_prefix(length: int) -> Callable[[Path], None]:
    def write(path: Path) -> None:
        source = path.with_name("source.mcap")
        write_recording(source, rounds=1)
        path.write_bytes(source.read_bytes()[:length])

    return write


def killed_before_first_flush(path: Path) -> None:
    """Copy a recording whose only message is still buffered: magic and header, nothing else."""
    source = path.with_name("source.mcap")
    with Ros2McapWriter(source, flush_period_s=NO_TIMER_FLUSH_S) as writer:
        channel = writer.add_channel("/clock", "rosgraph_msgs/msg/Clock", qos_profiles_yaml([]))
        writer.write(channel, serialize_message(Clock()), T0_NS, T0_NS)
        path.write_bytes(source.read_bytes())


def corrupt_chunk(path: Path) -> None:
    write_recording(path, rounds=3)
    with path.open("rb") as stream:
        summary = SeekingReader(stream).get_summary()
    assert summary is not None
    data = bytearray(path.read_bytes())
    data[summary.chunk_indexes[0].chunk_start_offset + 80] ^= 0xFF
    path.write_bytes(bytes(data))


BAD_RECORDINGS = {
    "missing": (lambda path: None, "no such recording"),
    "directory": (lambda path: path.mkdir(), "is a directory"),
    "empty": (lambda path: path.write_bytes(b""), "empty file"),
    "text": (lambda path: path.write_text("time,delta\n0,0.2\n"), r"not an MCAP file \(bad magic"),
    "cut in magic": (valid_prefix(5), "truncated inside the MCAP header"),
    "cut in header": (valid_prefix(20), "truncated inside the MCAP header"),
    "killed before flush": (killed_before_first_flush, "before its first flush"),
    "other profile": (
        lambda path: write_raw_mcap(path, profile="", schema=True, message_encoding="cdr"),
        "profile is '', expected 'ros2'",
    ),
    "no schema": (
        lambda path: write_raw_mcap(path, profile="ros2", schema=False, message_encoding="cdr"),
        "channel /clock has no schema",
    ),
    "json messages": (
        lambda path: write_raw_mcap(path, profile="ros2", schema=True, message_encoding="json"),
        "message encoding 'json', expected 'cdr'",
    ),
    "corrupt chunk": (corrupt_chunk, "corrupt MCAP data"),
}


@pytest.mark.parametrize("case", list(BAD_RECORDINGS))
def test_bad_recording_raises_one_line_error(tmp_path: Path, case: str) -> None:
    make, reason = BAD_RECORDINGS[case]
    path = tmp_path / "bad.mcap"
    make(path)
    with pytest.raises(RecordingError, match=reason) as error:
        list(read_messages(path))
    assert "\n" not in str(error.value) and str(path) in str(error.value)


BAD_CALLS = {
    "malformed type": (lambda: message_definition("JointState"), "expected a name like"),
    "unknown package": (
        lambda: message_definition("nni_msgs/msg/Rotor"),
        "package 'nni_msgs' is not in",
    ),
    "unknown message": (lambda: message_definition("sensor_msgs/msg/Rotor"), "no .*Rotor.msg"),
    "unknown class": (lambda: message_class("sensor_msgs/msg/Rotor"), "sensor_msgs.msg has no Rotor"),
    "uninstalled module": (lambda: message_class("nni_msgs/msg/Rotor"), "cannot import nni_msgs.msg"),
    "not cdr": (lambda: deserialize("rosgraph_msgs/msg/Clock", b"\x00\x01"), "bytes are not a CDR"),
    "qos not yaml": (lambda: parse_qos_profiles_yaml("- [unclosed"), "is not YAML"),
    "qos not a list": (lambda: parse_qos_profiles_yaml("history: keep_last"), "not a YAML list"),
    "qos missing key": (lambda: parse_qos_profiles_yaml("- history: keep_last"), "has no 'depth'"),
    "qos bad policy": (
        lambda: parse_qos_profiles_yaml(
            qos_profiles_yaml([OfferedQos()]).replace("reliable", "sometimes")
        ),
        "'sometimes' is not a reliability policy",
    ),
}


@pytest.mark.parametrize("case", list(BAD_CALLS))
def test_bad_type_or_qos_raises_one_line_error(case: str) -> None:
    call, reason = BAD_CALLS[case]
    with pytest.raises(RecordingError, match=reason) as error:
        call()
    assert "\n" not in str(error.value)
