"""The C37.118 byte-stream reassembler (nni_msgs_adapter.c37118.stream): whole frames out, bad ones counted.

Pure: bytes in, frames out.
"""

from __future__ import annotations

import random

from hypothesis import given
from hypothesis import strategies as st

from c37118_cases import EPOCH_NS, plant_config, plant_values
from nni_msgs_adapter.c37118 import frames as c37
from nni_msgs_adapter.c37118.stream import FrameReassembler

CONFIG = plant_config(2)
ENCODER = c37.DataFrameEncoder(CONFIG)
FRAMES = [c37.encode_config(CONFIG, c37.FrameType.CFG2, EPOCH_NS)] + [
    ENCODER.encode(EPOCH_NS + k * 20_000_000, plant_values(2, k)) for k in range(8)]


def feed_all(reader: FrameReassembler, data: bytes, chunks) -> list[bytes]:
    out, at = [], 0
    for size in chunks:
        out += reader.feed(data[at:at + size])
        at += size
    return out + reader.feed(data[at:])


@given(st.lists(st.integers(1, 200), max_size=40))
def test_frames_come_out_whole_however_the_bytes_are_cut(chunks):
    reader = FrameReassembler()
    assert feed_all(reader, b"".join(FRAMES), chunks) == FRAMES
    assert reader.rejected == {} and reader.buffered_bytes == 0 and reader.frames == len(FRAMES)


def test_garbage_between_frames_is_one_bad_sync_per_run():
    reader = FrameReassembler()
    data = b"garbage" + FRAMES[0] + b"\x00\x01\x02" + FRAMES[1] + FRAMES[2]
    assert reader.feed(data) == FRAMES[:3]
    assert reader.rejected == {"bad_sync": 2} and reader.skipped_bytes == 10


def test_a_bad_crc_is_skipped_and_the_next_frame_read():
    damaged = bytearray(FRAMES[1])
    damaged[30] ^= 0xFF
    reader = FrameReassembler()
    assert reader.feed(FRAMES[0] + bytes(damaged) + FRAMES[2]) == [FRAMES[0], FRAMES[2]]
    assert reader.rejected == {"bad_crc": 1}


def test_a_truncated_frame_is_told_from_a_damaged_one():
    reader = FrameReassembler()
    assert reader.feed(FRAMES[1][:40] + FRAMES[2] + FRAMES[3]) == [FRAMES[2], FRAMES[3]]
    assert reader.rejected == {"truncated": 1}


def test_a_wrong_sync_word_and_an_oversized_framesize_are_resynchronised():
    wrong_sync = bytearray(FRAMES[1])
    wrong_sync[1] = 0x72  # frame type 7
    oversized = bytearray(FRAMES[2])
    oversized[2:4] = (60000).to_bytes(2, "big")
    reader = FrameReassembler(max_frame_bytes=2000)
    assert reader.feed(bytes(wrong_sync) + FRAMES[3] + bytes(oversized) + FRAMES[4]) == [FRAMES[3], FRAMES[4]]
    assert reader.rejected == {"unknown_type": 1, "oversized": 1}


def test_a_frame_left_incomplete_when_the_stream_ends_is_truncated():
    reader = FrameReassembler()
    assert reader.feed(FRAMES[0] + FRAMES[1][:10]) == [FRAMES[0]]
    assert reader.buffered_bytes == 10
    reader.finish()
    assert reader.rejected == {"truncated": 1} and reader.buffered_bytes == 0


def test_buffered_bytes_stay_below_one_frame_whatever_comes():
    reader = FrameReassembler(max_frame_bytes=512)
    rng = random.Random(3)
    worst = 0
    for _ in range(2000):
        chunk = bytes(rng.choice([0xAA, 0x32, 0x01, 0xFF, rng.randrange(256)]) for _ in range(rng.randrange(1, 300)))
        reader.feed(chunk)
        worst = max(worst, reader.buffered_bytes)
    assert worst < 512
    data_frames = b"".join(FRAMES[1:])
    assert reader.feed(data_frames * 8)[-len(FRAMES[1:]):] == FRAMES[1:]


@given(st.binary(max_size=2000))
def test_after_any_garbage_the_stream_is_found_again_within_one_bound(garbage):
    """A garbage tail can claim a FRAMESIZE reaching up to the bound into the frames after it, never further."""
    stream = b"".join(FRAMES)
    assert len(stream) > 1000
    reader = FrameReassembler(max_frame_bytes=1000)
    out = reader.feed(garbage + stream + stream)
    assert out[-len(FRAMES):] == FRAMES
    assert set(reader.rejected) <= set(c37.FrameError.REASONS) and sum(reader.rejected.values()) <= 2
