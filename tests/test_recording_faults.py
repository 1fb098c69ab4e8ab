"""Damaged and hostile recordings, as `nni-replay` meets them (a real process on real files).

A truncated file is reported (how many messages, up to which time) and refused for --rrd unless
--allow-partial; a duplicated chunk is read once; chunks that claim or inflate to more than the
cap are refused at once; a FIFO is refused instead of blocking open(); a NaN in one true state
leaves that sample out, said on stderr, and the rest readable. Also the schema text we write
against the shipped recordings, byte for byte, and the RIHS01 hashes against rosidl's.
"""

from __future__ import annotations

import io
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zstandard
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from rclpy.serialization import serialize_message
from rosbags.typesys import Stores, get_typestore

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.recording.mcap_io import (
    MAX_CHUNK_BYTES, MCAP_MAGIC, Ros2McapWriter, message_definition, qos_profiles_yaml, read_recording, type_hash,
)
from nni_msgs_adapter.recording.runs import read_generator_run

NNI_REPLAY = Path(sys.executable).parent / "nni-replay"
RECORDINGS = Path(__file__).resolve().parent.parent / "recordings"
SHIPPED = RECORDINGS / "paper_b0.3.mcap"
START_NS = 1_700_000_000 * 1_000_000_000
PERIOD_NS = 20_000_000
CONTRACT_TYPES = sorted({type_name for type_name, _, _ in contract.TOPICS.values()})


def replay(*args, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([str(NNI_REPLAY), *map(str, args)], capture_output=True, text=True, timeout=timeout)


def assert_one_line_error(result: subprocess.CompletedProcess, *words: str) -> None:
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, result.stdout + result.stderr
    assert len(lines) == 1 and lines[0].startswith("nni-replay: error: "), result.stderr
    for word in words:
        assert word in lines[0], lines[0]


def write_run(path: Path, states: int, *, nan_at: int | None = None, flush_every: int = 0) -> None:
    """A small realtime-style run: plant and controller states every 20 ms; Omega latched at the start."""
    with Ros2McapWriter(path, flush_period_s=3600.0) as writer:
        channels = {name: writer.add_channel("/" + name, contract.TOPICS[name][0],
                                             qos_profiles_yaml([contract.TOPICS[name][2]]))
                    for name in (contract.TOPIC_INVARIANT_SET, contract.TOPIC_PLANT_STATE,
                                 contract.TOPIC_CONTROLLER_STATE)}
        boundary = [(-1.0, 0.0), (0.0, 1.0), (1.0, 0.0), (0.0, -1.0)]
        writer.write(channels[contract.TOPIC_INVARIANT_SET],
                     serialize_message(contract.invariant_set_message(START_NS, boundary)), START_NS, START_NS)
        for k in range(states):
            stamp = START_NS + k * PERIOD_NS
            delta = math.nan if k == nan_at else 0.9 + 0.001 * k
            writer.write(channels[contract.TOPIC_PLANT_STATE],
                         serialize_message(contract.plant_state_message(stamp, delta, 0.01 * k, 0.1)), stamp, stamp)
            writer.write(channels[contract.TOPIC_CONTROLLER_STATE],
                         serialize_message(contract.controller_state_message(stamp, 0.001 * k, 0.0, 0.1, 0.1, False,
                                                                             0.2, 0.3)), stamp, stamp)
            if flush_every and (k + 1) % flush_every == 0:
                writer.flush()


def top_level_records(path: Path) -> list[tuple[int, int, int]]:
    """(opcode, start offset, end offset) of every top-level record after the magic."""
    data, offset, out = path.read_bytes(), len(MCAP_MAGIC), []
    while offset + 9 <= len(data):
        opcode, length = data[offset], int.from_bytes(data[offset + 1:offset + 9], "little")
        out.append((opcode, offset, offset + 9 + length))
        offset += 9 + length
    return out


# --------------------------------------------------------------------------------------------
# truncated, duplicated
# --------------------------------------------------------------------------------------------


def test_a_truncated_recording_is_reported_and_refused_for_rrd_unless_allowed(tmp_path):
    """Cut the shipped lockstep run at half its size: today's reader gave 33 of 501 states, exit 0."""
    cut, out = tmp_path / "cut.mcap", tmp_path / "out.rrd"
    data = SHIPPED.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    kept = read_recording(cut)
    assert not kept.complete and 0 < len(kept.messages) < len(read_recording(SHIPPED).messages)
    span_s = (kept.messages[-1].log_time_ns - kept.messages[0].log_time_ns) * 1e-9

    refused = replay(cut, "--rrd", out)
    assert_one_line_error(refused, "incomplete recording", f"{len(kept.messages)} messages", f"{span_s:.3f} s",
                          "--allow-partial")
    assert not out.exists()

    allowed = replay(cut, "--rrd", out, "--allow-partial")
    assert allowed.returncode == 0, allowed.stderr
    assert "warning" in allowed.stderr and f"{len(kept.messages)} messages" in allowed.stderr
    assert out.exists()

    info = replay(cut, "--info")
    assert info.returncode == 0, info.stderr
    assert f"Complete:          no: {cut}: incomplete recording" in info.stdout
    assert f"Messages:          {len(kept.messages)}" in info.stdout


def test_a_duplicated_chunk_is_read_once(tmp_path):
    """An unfinished file (killed logger) in which its first chunk appears twice."""
    whole, doubled = tmp_path / "whole.mcap", tmp_path / "doubled.mcap"
    write_run(whole, 30, flush_every=10)
    records = top_level_records(whole)
    chunks = [(start, end) for opcode, start, end in records if opcode == 0x06]
    assert len(chunks) >= 3
    data = whole.read_bytes()
    first_start, first_end = chunks[0]
    summary_start = next(start for opcode, start, _ in records if opcode == 0x0F)  # DataEnd: the data section ends
    doubled.write_bytes(data[:summary_start] + data[first_start:first_end])  # no summary: cut after the copy

    expected = read_recording(whole).messages
    read = read_recording(doubled)
    assert not read.complete
    assert read.duplicate_chunks == 1
    assert read.messages == expected, "every message once, in order"

    info = replay(doubled, "--info")
    assert info.returncode == 0, info.stderr
    assert "1 chunk(s) repeat an earlier one: each read once" in info.stderr
    assert f"Messages:          {len(expected)}" in info.stdout


# --------------------------------------------------------------------------------------------
# size caps, FIFO
# --------------------------------------------------------------------------------------------


def bomb(path: Path, claimed_size: int, inflated_size: int) -> None:
    """A valid file header and channel, then one zstd chunk of zeros inflating to ``inflated_size``."""
    write_run(path, 1)
    records = top_level_records(path)
    header_end = next(end for opcode, _, end in records if opcode == 0x01)
    compressor = zstandard.ZstdCompressor().compressobj()
    zeros = bytes(2**20)
    compressed = b"".join(compressor.compress(zeros) for _ in range(inflated_size // len(zeros))) + compressor.flush()
    chunk = Chunk(compression="zstd", data=compressed, message_start_time=START_NS, message_end_time=START_NS,
                  uncompressed_crc=0, uncompressed_size=claimed_size)
    from mcap.data_stream import RecordBuilder

    builder = RecordBuilder()
    chunk.write(builder)
    path.write_bytes(path.read_bytes()[:header_end] + builder.end())


@pytest.mark.parametrize("claim", ["claims_a_gibibyte", "claims_little_inflates_to_much"])
def test_a_chunk_beyond_the_cap_is_refused_at_once(tmp_path, claim):
    path = tmp_path / "bomb.mcap"
    inflated = 4 * MAX_CHUNK_BYTES
    bomb(path, 2**30 if claim == "claims_a_gibibyte" else 2**20, inflated)
    assert path.stat().st_size < 200_000, "a small file"
    started = time.monotonic()
    result = replay(path, "--rrd", tmp_path / "out.rrd", "--allow-partial", timeout=60)
    assert_one_line_error(result, str(path), "claims" if claim == "claims_a_gibibyte" else "decompresses to more")
    assert time.monotonic() - started < 20, "refused at once, not after inflating"
    assert not (tmp_path / "out.rrd").exists()


def test_a_fifo_is_refused_instead_of_blocking(tmp_path):
    fifo = tmp_path / "x.mcap"
    os.mkfifo(fifo)
    result = replay(fifo, "--info", timeout=30)
    assert_one_line_error(result, "not a regular file")


# --------------------------------------------------------------------------------------------
# NaN in one state
# --------------------------------------------------------------------------------------------


def test_a_nan_state_is_reported_and_the_rest_stays_readable(tmp_path):
    path, out = tmp_path / "nan.mcap", tmp_path / "out.rrd"
    write_run(path, 20, nan_at=7)
    run = read_generator_run(path)
    assert run.stamp_ns.size == 19, "the NaN sample is left out, the 19 others kept"
    assert START_NS + 7 * PERIOD_NS not in run.stamp_ns.tolist()
    assert len(run.skipped) == 1 and "/plant/state" in run.skipped[0] and "non-finite" in run.skipped[0]
    result = replay(path, "--rrd", out)
    assert result.returncode == 0, result.stderr
    assert "sample left out" in result.stderr and "non-finite" in result.stderr
    assert out.exists()


# --------------------------------------------------------------------------------------------
# what the library writes and what rosbag2 writes
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("case", sorted(path.name for path in RECORDINGS.glob("*.mcap")))
def test_schema_text_is_byte_for_byte_what_the_shipped_recordings_hold(case):
    """The hand-written rosbag2 definition text, against the files made before the split."""
    with (RECORDINGS / case).open("rb") as stream:
        summary = make_reader(stream).get_summary()
    schemas = {schema.name: schema.data for schema in summary.schemas.values()}
    assert sorted(schemas) == CONTRACT_TYPES
    for type_name, data in schemas.items():
        assert message_definition(type_name).encode() == data, type_name
    hashes = {summary.channels[cid].topic: summary.channels[cid].metadata["topic_type_hash"]
              for cid in summary.channels}
    for channel in summary.channels.values():
        assert hashes[channel.topic] == type_hash(summary.schemas[channel.schema_id].name)


@pytest.mark.parametrize("type_name", CONTRACT_TYPES)
def test_type_hash_is_rosidl_s_and_rosbags_definition_is_not_rosbag2_s(type_name):
    package, namespace, name = type_name.split("/")
    generated = json.loads((Path(sys.prefix) / "share" / package / namespace / f"{name}.json").read_text())
    [rosidl_hash] = [entry["hash_string"] for entry in generated["type_hashes"] if entry["type_name"] == type_name]
    assert type_hash(type_name) == rosidl_hash
    # Why the definition stays hand-written: rosbags drops the .msg comments rosbag2 keeps.
    rosbags_text, _ = get_typestore(Stores.ROS2_JAZZY).generate_msgdef(type_name, ros_version=2)
    assert rosbags_text != message_definition(type_name)
    assert "#" in message_definition(type_name) and "#" not in rosbags_text


def test_stream_reader_sees_the_same_records_as_ours(tmp_path):
    """Our sequential pass and mcap's StreamReader agree on a finished file of several chunks."""
    path = tmp_path / "run.mcap"
    write_run(path, 30, flush_every=10)
    with path.open("rb") as stream:
        theirs = [record for record in StreamReader(io.BufferedReader(stream)).records
                  if type(record).__name__ == "Message"]
    assert [bytes(m.data) for m in theirs] == [m.cdr_bytes for m in read_recording(path).messages]
