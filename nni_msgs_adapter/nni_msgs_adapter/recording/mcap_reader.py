"""Read a ROS 2 MCAP recording, finished or cut short, without trusting it.

Hand-written around the mcap library's record parsers because no library does all of this:

* only regular files are opened (a FIFO named ``x.mcap`` would block ``open()`` forever);
* every record and every decompressed chunk is capped (:data:`MAX_RECORD_BYTES`,
  :data:`MAX_CHUNK_BYTES`, :data:`MAX_TOTAL_BYTES`): a small file whose chunk claims, or
  inflates to, a gibibyte is refused before the memory is taken;
* a file without its footer (a recorder killed, or its disk full) is read up to its last
  complete record and reported as incomplete (:attr:`Recording.complete`), never passed off as
  whole;
* a chunk that appears twice (a damaged or badly concatenated file) is read once and counted
  (:attr:`Recording.duplicate_chunks`).

The file is read in one sequential pass (recordings are small: 115 kB for 10 s at 50 frames/s);
messages come back in log-time order, file order among equal times (what the indexed reader
gave for our files). Metadata records (``nni_run``, ``rosbag2``) come back by name.
"""

from __future__ import annotations

import io
import os
import stat
import struct
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO, Iterator, NamedTuple

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk

from nni_msgs_adapter.recording.mcap_profile import MESSAGE_ENCODING, PROFILE, RecordingError
from nni_msgs_adapter.recording.mcap_qos import QOS_METADATA_KEY

MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Largest top-level record read, bytes (a chunk's compressed body included). Our writer closes
#: chunks at 1 MiB, rosbag2's largest preset at 4 MiB.
MAX_RECORD_BYTES = 64 * 2**20
#: Largest chunk after decompression, bytes (the size its header claims, checked again on the output).
MAX_CHUNK_BYTES = 64 * 2**20
#: Largest total of decompressed chunks in one recording, bytes (hours of a 50 frames/s run).
MAX_TOTAL_BYTES = 512 * 2**20

# Every MCAP record starts with a one-byte opcode and an eight-byte little-endian body length.
_RECORD_PREFIX = struct.Struct("<BQ")
# A Footer body is summary_start (u64), summary_offset_start (u64) and summary_crc (u32).
_FOOTER_BODY_LENGTH = 8 + 8 + 4
_FOOTER_PREFIX = _RECORD_PREFIX.pack(Opcode.FOOTER, _FOOTER_BODY_LENGTH)
_FOOTER_AND_MAGIC_LENGTH = _RECORD_PREFIX.size + _FOOTER_BODY_LENGTH + len(MCAP_MAGIC)
# What parsing or decompressing a damaged record raises in the mcap library and zstandard.
_CORRUPT_DATA_ERRORS = (McapError, CRCValidationError, zstandard.ZstdError, struct.error, UnicodeDecodeError)
_SUPPORTED_COMPRESSIONS = ("", "zstd")


class RecordedMessage(NamedTuple):
    """One message of a recording, still serialized.

    Attributes
    ----------
    topic : str
        Topic name.
    type_name : str
        Full message type (the channel's schema name).
    log_time_ns, publish_time_ns : int
        Reception and publication times, nanoseconds since the epoch.
    cdr_bytes : bytes
        The CDR message (decode with :func:`mcap_profile.deserialize`).
    qos_yaml : str
        The channel's ``offered_qos_profiles`` (parse with :func:`mcap_qos.parse_qos_profiles_yaml`).
    """

    topic: str
    type_name: str
    log_time_ns: int
    publish_time_ns: int
    cdr_bytes: bytes
    qos_yaml: str


@dataclass(frozen=True)
class Recording:
    """What a recording file holds.

    Attributes
    ----------
    path : Path
        The file.
    messages : tuple of RecordedMessage
        Every message read, in log-time order.
    complete : bool
        The file is finished (footer present). False: it was cut short and ``messages`` are
        those of its complete records only.
    metadata : dict of str to dict of str to str
        Metadata records by name (``nni_run``, ``rosbag2``, ...).
    duplicate_chunks : int
        Chunks that repeated an earlier chunk byte for byte, read once.
    """

    path: Path
    messages: tuple
    complete: bool
    metadata: dict = field(default_factory=dict)
    duplicate_chunks: int = 0

    def incompleteness(self) -> str:
        """One line on what a cut recording still holds (how many messages, up to which time)."""
        first, last = self.messages[0].log_time_ns, self.messages[-1].log_time_ns
        return (f"{self.path}: incomplete recording (no summary: its recorder was killed or could not finish "
                f"the file): {len(self.messages)} messages, up to {(last - first) * 1e-9:.3f} s after the first")


def _open_regular(path: Path) -> IO[bytes]:
    """Open *path* for reading if it is a regular file; never blocks on a FIFO or a device."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such recording") from None
    except IsADirectoryError:
        raise RecordingError(f"{path}: is a directory, not an MCAP file") from None
    except OSError as error:
        raise RecordingError(f"{path}: cannot open: {error.strerror}") from None
    mode = os.fstat(fd).st_mode
    if stat.S_ISDIR(mode):
        os.close(fd)
        raise RecordingError(f"{path}: is a directory, not an MCAP file")
    if not stat.S_ISREG(mode):
        os.close(fd)
        raise RecordingError(f"{path}: not a regular file (a FIFO, socket or device), not an MCAP recording")
    return os.fdopen(fd, "rb")


def _check_header(path: Path, stream: IO[bytes], size: int) -> None:
    """Raise :class:`RecordingError` unless the stream starts with a complete ``ros2`` MCAP header."""
    magic = stream.read(len(MCAP_MAGIC))
    if not magic:
        raise RecordingError(f"{path}: empty file, not an MCAP recording")
    if not MCAP_MAGIC.startswith(magic):
        raise RecordingError(f"{path}: not an MCAP file (bad magic bytes)")
    prefix = stream.read(_RECORD_PREFIX.size)
    if len(prefix) < _RECORD_PREFIX.size:
        raise RecordingError(f"{path}: truncated inside the MCAP header")
    opcode, length = _RECORD_PREFIX.unpack(prefix)
    if opcode != Opcode.HEADER:
        raise RecordingError(f"{path}: not an MCAP file (no header record after the magic)")
    if stream.tell() + length > size:
        raise RecordingError(f"{path}: truncated inside the MCAP header")
    if length > MAX_RECORD_BYTES:
        raise RecordingError(f"{path}: MCAP header of {length} bytes, more than the {MAX_RECORD_BYTES} allowed")
    try:
        profile = Header.read(ReadDataStream(io.BytesIO(stream.read(length)))).profile
    except _CORRUPT_DATA_ERRORS:
        raise RecordingError(f"{path}: corrupt MCAP header record") from None
    if profile != PROFILE:
        raise RecordingError(f"{path}: MCAP profile is {profile!r}, expected {PROFILE!r}")


class _PrefixStream:
    """Read-only view of the first *length* bytes of a binary stream (then end of file)."""

    def __init__(self, stream: IO[bytes], length: int) -> None:
        self._stream = stream
        self._remaining = length

    def read(self, size: int) -> bytes:
        data = self._stream.read(min(size, self._remaining))
        self._remaining -= len(data)
        return data


def _has_footer(stream: IO[bytes], size: int) -> bool:
    """Whether the file ends with a Footer record and the closing magic (a finished file)."""
    if size < len(MCAP_MAGIC) + _FOOTER_AND_MAGIC_LENGTH:
        return False
    stream.seek(size - _FOOTER_AND_MAGIC_LENGTH)
    tail = stream.read(_FOOTER_AND_MAGIC_LENGTH)
    return tail.startswith(_FOOTER_PREFIX) and tail.endswith(MCAP_MAGIC)


def _complete_records_end(stream: IO[bytes], size: int) -> int:
    """Offset just past the last top-level record that lies entirely within the file."""
    end = len(MCAP_MAGIC)
    while end + _RECORD_PREFIX.size <= size:
        stream.seek(end)
        _, length = _RECORD_PREFIX.unpack(stream.read(_RECORD_PREFIX.size))
        record_end = end + _RECORD_PREFIX.size + length
        if record_end > size:
            break
        end = record_end
    return end


def _decompressed(path: Path, chunk: Chunk) -> bytes:
    """The chunk's records, decompressed with its claimed size checked and the output bounded."""
    if chunk.compression not in _SUPPORTED_COMPRESSIONS:
        raise RecordingError(f"{path}: chunk compressed with {chunk.compression!r}, "
                             f"not one of {', '.join(repr(c) for c in _SUPPORTED_COMPRESSIONS)}")
    if chunk.uncompressed_size > MAX_CHUNK_BYTES:
        raise RecordingError(f"{path}: a chunk claims {chunk.uncompressed_size} bytes uncompressed, "
                             f"more than the {MAX_CHUNK_BYTES} allowed")
    if chunk.compression == "":
        data = bytes(chunk.data)
    else:
        reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(chunk.data))
        parts, total = [], 0
        while total <= chunk.uncompressed_size:
            block = reader.read(min(2**20, chunk.uncompressed_size + 1 - total))
            if not block:
                break
            parts.append(block)
            total += len(block)
        data = b"".join(parts)
    if len(data) != chunk.uncompressed_size:
        raise RecordingError(f"{path}: a chunk decompresses to more or less than the "
                             f"{chunk.uncompressed_size} bytes it claims")
    return data


def _recorded_message(path: Path, schema: Schema | None, channel: Channel, message: Message) -> RecordedMessage:
    if schema is None:
        raise RecordingError(f"{path}: channel {channel.topic} has no schema, so its message type is unknown")
    if channel.message_encoding != MESSAGE_ENCODING:
        raise RecordingError(f"{path}: channel {channel.topic} has message encoding "
                             f"{channel.message_encoding!r}, expected {MESSAGE_ENCODING!r}")
    return RecordedMessage(
        topic=channel.topic,
        type_name=schema.name,
        log_time_ns=message.log_time,
        publish_time_ns=message.publish_time,
        cdr_bytes=bytes(message.data),
        qos_yaml=channel.metadata.get(QOS_METADATA_KEY, ""),
    )


class _Collector:
    """Schemas, channels, messages and metadata of one sequential pass, chunks deduplicated."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.messages: list[RecordedMessage] = []
        self.metadata: dict[str, dict[str, str]] = {}
        self.chunk_keys: set = set()
        self.duplicate_chunks = 0
        self.decompressed_bytes = 0

    def take(self, record) -> None:
        if isinstance(record, Chunk):
            self._take_chunk(record)
        elif isinstance(record, Schema):
            self.schemas[record.id] = record
        elif isinstance(record, Channel):
            self.channels[record.id] = record
        elif isinstance(record, Message):
            if record.channel_id not in self.channels:
                raise RecordingError(f"{self.path}: message on channel {record.channel_id}, "
                                     "which is not defined before it")
            channel = self.channels[record.channel_id]
            self.messages.append(_recorded_message(self.path, self.schemas.get(channel.schema_id), channel, record))
        elif isinstance(record, Metadata):
            self.metadata[record.name] = dict(record.metadata)

    def _take_chunk(self, chunk: Chunk) -> None:
        key = (chunk.message_start_time, chunk.message_end_time, chunk.uncompressed_size, chunk.uncompressed_crc,
               chunk.compression, bytes(chunk.data))
        if key in self.chunk_keys:
            self.duplicate_chunks += 1
            return
        self.chunk_keys.add(key)
        data = _decompressed(self.path, chunk)
        self.decompressed_bytes += len(data)
        if self.decompressed_bytes > MAX_TOTAL_BYTES:
            raise RecordingError(f"{self.path}: more than {MAX_TOTAL_BYTES} bytes of messages once decompressed: "
                                 "refused (the limit bounds memory)")
        for inner in breakup_chunk(replace(chunk, compression="", data=data), validate_crc=True):
            self.take(inner)


def read_recording(path: str | os.PathLike[str]) -> Recording:
    """Read a ROS 2 MCAP recording, finished or cut short.

    A file without a footer, left by a recorder killed mid-write, is read up to its last complete
    record: every message of every chunk that reached the file, and ``complete`` is False.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mcap`` file.

    Returns
    -------
    Recording

    Raises
    ------
    RecordingError
        The file is missing, not a regular file, empty, not MCAP (bad magic), cut inside its
        header, not of the ``ros2`` profile, has a channel without schema or not in CDR, is
        corrupt (CRC, a chunk that does not decompress to its size), exceeds a size cap, or is
        unfinished with no complete message.
    """
    recording = Path(path)
    with _open_regular(recording) as stream:
        size = os.fstat(stream.fileno()).st_size
        _check_header(recording, stream, size)
        complete = _has_footer(stream, size)
        length = size if complete else _complete_records_end(stream, size)
        stream.seek(0)
        collector = _Collector(recording)
        reader = StreamReader(_PrefixStream(stream, length), validate_crcs=True, emit_chunks=True,
                              record_size_limit=MAX_RECORD_BYTES)
        try:
            for record in reader.records:
                collector.take(record)
        except EndOfFile:
            if complete:
                raise RecordingError(f"{recording}: corrupt MCAP data: a record runs past its footer") from None
        except _CORRUPT_DATA_ERRORS as error:
            raise RecordingError(f"{recording}: corrupt MCAP data: {error}") from None
    if not complete and not collector.messages:
        raise RecordingError(f"{recording}: unfinished recording (no summary) with no complete message: "
                             "cut before its first flush")
    messages = tuple(sorted(collector.messages, key=lambda message: message.log_time_ns))
    return Recording(recording, messages, complete, collector.metadata, collector.duplicate_chunks)


def read_messages(path: str | os.PathLike[str]) -> Iterator[RecordedMessage]:
    """The messages of :func:`read_recording`, in log-time order (complete or not: check it there).

    Raises
    ------
    RecordingError
        As :func:`read_recording`, before this returns.
    """
    return iter(read_recording(path).messages)
