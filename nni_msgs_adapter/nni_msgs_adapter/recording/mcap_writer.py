"""Write a ROS 2 (Jazzy) MCAP as ``ros2 bag record -s mcap`` does, and keep it readable when things go wrong.

A file written here is what rosbag2 0.26 writes for the same topics: profile ``ros2``; one schema
per message type (:mod:`mcap_profile`); one channel per topic with message encoding ``cdr`` and
the channel metadata ``offered_qos_profiles`` (:mod:`mcap_qos`) and ``topic_type_hash`` (RIHS01);
``log_time`` in nanoseconds since the epoch; a summary with chunk and message indexes and
statistics; at the end a ``rosbag2`` metadata record (``serialized_metadata``, the bag's
metadata YAML with ``ros_distro: jazzy``, and ``ROS_DISTRO``), which is where ``ros2 bag info``
reads "ROS Distro". mcap-ros2-support's writer does none of the channel metadata, so this uses
the low-level :class:`mcap.writer.Writer`.

Hand-written on purpose, because no library does it:

* a background thread closes the current chunk and flushes the file at least once every
  ``flush_period_s`` seconds, so a recorder killed with SIGKILL leaves a file whose complete
  chunks :func:`mcap_reader.read_recording` still reads;
* the first failure to write (a full disk: ENOSPC, a file size limit) or the file vanishing
  under the writer (its folder removed) stops the writer, is kept in :attr:`Ros2McapWriter.failure`
  and reported once through ``on_failure``; what reached the file before it stays readable.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path
from typing import Callable

import yaml
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from nni_msgs_adapter.recording.mcap_profile import (
    MESSAGE_ENCODING, PROFILE, SCHEMA_ENCODING, RecordingError, _parse_type_name, message_definition, type_hash,
)
from nni_msgs_adapter.recording.mcap_qos import QOS_METADATA_KEY

TYPE_HASH_METADATA_KEY = "topic_type_hash"
#: The ROS 2 distribution the recordings are for (what ``ros2 bag info`` shows as "ROS Distro").
ROS_DISTRO = "jazzy"
#: Name and keys of rosbag2's own metadata record in an MCAP (rosbag2_storage_mcap).
ROSBAG2_METADATA_NAME = "rosbag2"
ROSBAG2_SERIALIZED_METADATA_KEY = "serialized_metadata"
ROSBAG2_DISTRO_KEY = "ROS_DISTRO"
#: rosbag2 metadata version of Jazzy (QoS policies as names).
ROSBAG2_METADATA_VERSION = 9


class WriteFailure(OSError):
    """The recording could not be written any more (disk full, file removed); one-line reason."""


class Ros2McapWriter:
    """Write a rosbag2-compatible MCAP file that survives being killed.

    Messages are buffered in a zstd-compressed chunk; a background thread closes the chunk
    and flushes the file every *flush_period_s* seconds (a chunk also closes when it exceeds
    1 MiB). After SIGKILL the file lacks its summary but :func:`mcap_reader.read_recording`
    recovers every message flushed before the kill. :meth:`close` (or leaving the ``with``
    block) writes the rosbag2 metadata and the summary: schemas, channels, statistics, chunk
    indexes (message indexes follow each chunk).

    All methods are thread-safe.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mcap`` file to create (replaced if it exists).
    flush_period_s : float, optional
        Longest time, in seconds, that a written message waits before it is in the file.
    on_failure : callable, optional
        Called once, with the :class:`WriteFailure`, from whichever thread meets the first
        write failure (the flush thread, or the caller of :meth:`write`).

    Examples
    --------
    >>> with Ros2McapWriter("run.mcap") as writer:  # doctest: +SKIP
    ...     joints = writer.add_channel(
    ...         "/pmu", "sensor_msgs/msg/JointState", qos_profiles_yaml([OfferedQos()]))
    ...     writer.write(joints, serialize(msg), log_time_ns, publish_time_ns)
    """

    def __init__(self, path: str | os.PathLike[str], *, flush_period_s: float = 1.0,
                 on_failure: Callable[[WriteFailure], None] | None = None) -> None:
        if not flush_period_s > 0:
            raise ValueError(f"flush_period_s must be positive, not {flush_period_s}")
        self.path = Path(path)
        self._lock = threading.RLock()  # re-entrant: on_failure may ask for counts
        self._on_failure = on_failure
        self.failure: WriteFailure | None = None
        self._file = self.path.open("wb")
        self._identity = os.fstat(self._file.fileno())
        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library=f"nni_msgs_adapter {LIBRARY_IDENTIFIER}")
        self._writer.flush()
        self._schema_ids: dict[str, int] = {}
        self._channels: dict[int, tuple[str, str, str, str]] = {}  # id -> (topic, type, QoS YAML, hash)
        self._channel_ids: dict[str, int] = {}  # topic -> channel id
        self._counts: dict[str, int] = {}
        self._flushed = 0  # messages in the file as of the last successful flush
        self._log_time_range: tuple[int, int] | None = None
        self._closed = False
        self._stop_flushing = threading.Event()
        self._flusher = threading.Thread(
            target=self._flush_periodically,
            args=(flush_period_s,),
            name=f"mcap-flush {self.path.name}",
            daemon=True,
        )
        self._flusher.start()

    def __enter__(self) -> Ros2McapWriter:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @property
    def counts(self) -> dict[str, int]:
        """Messages written so far per topic (a copy)."""
        with self._lock:
            return dict(self._counts)

    @property
    def flushed(self) -> int:
        """Messages known to be in the file: those written before the last successful flush."""
        with self._lock:
            return self._flushed

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write a Metadata record now (outside any chunk, flushed: a killed file keeps it).

        Raises
        ------
        WriteFailure
            If the file can no longer be written.
        ValueError
            If the writer is closed, or a key or value is not a string.
        """
        if not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
            raise ValueError(f"metadata {name!r}: keys and values must be strings")
        with self._lock:
            self._check_writable()
            self._guarded(lambda: (self._writer.add_metadata(name, data), self._file.flush()))

    def add_channel(self, topic: str, type_name: str, qos_yaml: str) -> int:
        """Register a topic; its type's schema is written the first time the type is seen.

        Parameters
        ----------
        topic : str
            Fully qualified topic name, e.g. ``"/gen1/pmu"``.
        type_name : str
            Full message type, e.g. ``"sensor_msgs/msg/JointState"``.
        qos_yaml : str
            The ``offered_qos_profiles`` metadata, normally from :func:`mcap_qos.qos_profiles_yaml`.

        Returns
        -------
        int
            The channel id to pass to :meth:`write`. Adding a topic again with the same type
            returns its existing id.

        Raises
        ------
        RecordingError
            If *type_name* is not a full name of an installed message type.
        ValueError
            If *topic* was added with another type, or the writer is closed.
        WriteFailure
            If the file can no longer be written.
        """
        if _parse_type_name(type_name).full != type_name:
            raise RecordingError(f"message type {type_name!r} is not a full name like sensor_msgs/msg/JointState")
        definition = message_definition(type_name)
        digest = type_hash(type_name)
        with self._lock:
            self._check_writable()
            if topic in self._channel_ids:
                channel_id = self._channel_ids[topic]
                if self._channels[channel_id][1] != type_name:
                    raise ValueError(f"topic {topic} is already recorded as {self._channels[channel_id][1]}")
                return channel_id
            if type_name not in self._schema_ids:
                self._schema_ids[type_name] = self._guarded(lambda: self._writer.register_schema(
                    name=type_name, encoding=SCHEMA_ENCODING, data=definition.encode()))
            channel_id = self._guarded(lambda: self._writer.register_channel(
                topic=topic,
                message_encoding=MESSAGE_ENCODING,
                schema_id=self._schema_ids[type_name],
                metadata={QOS_METADATA_KEY: qos_yaml, TYPE_HASH_METADATA_KEY: digest},
            ))
            self._channels[channel_id] = (topic, type_name, qos_yaml, digest)
            self._channel_ids[topic] = channel_id
            self._counts[topic] = 0
            return channel_id

    def write(self, channel_id: int, cdr_bytes: bytes, log_time_ns: int, publish_time_ns: int) -> None:
        """Append one serialized message.

        Parameters
        ----------
        channel_id : int
            An id returned by :meth:`add_channel`.
        cdr_bytes : bytes
            The message in CDR, as :func:`mcap_profile.serialize` returns it.
        log_time_ns : int
            Reception time, nanoseconds since the epoch (rosbag2's ``recv_timestamp``).
        publish_time_ns : int
            Publication time, nanoseconds since the epoch (rosbag2's ``send_timestamp``: the
            DDS source timestamp).

        Raises
        ------
        ValueError
            If the channel id is unknown or the writer is closed.
        WriteFailure
            If the file can no longer be written (the message is not counted).
        """
        with self._lock:
            self._check_writable()
            if channel_id not in self._channels:
                raise ValueError(f"no channel with id {channel_id}")
            self._guarded(lambda: self._writer.add_message(
                channel_id=channel_id, log_time=log_time_ns, data=cdr_bytes, publish_time=publish_time_ns))
            self._counts[self._channels[channel_id][0]] += 1
            first, last = self._log_time_range or (log_time_ns, log_time_ns)
            self._log_time_range = (min(first, log_time_ns), max(last, log_time_ns))

    def flush(self) -> None:
        """Close the current chunk (if it holds messages) and flush the file now."""
        with self._lock:
            self._check_writable()
            self._guarded(self._flush_and_check)

    def close(self) -> None:
        """Write the rosbag2 metadata and the summary and close the file; later calls do nothing.

        After a write failure the file is only closed (no summary: the disk is full or the file
        gone); what was flushed before the failure stays readable as an incomplete recording.
        """
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._stop_flushing.set()
        self._flusher.join()
        with self._lock:
            if self.failure is None:
                self._guarded(self._finish)
            try:
                self._file.close()
            except OSError:
                pass  # the failure is already recorded; closing only releases the descriptor

    def _finish(self) -> None:
        self._writer.add_metadata(ROSBAG2_METADATA_NAME, {
            ROSBAG2_SERIALIZED_METADATA_KEY: self._rosbag2_metadata_yaml(),
            ROSBAG2_DISTRO_KEY: ROS_DISTRO,
        })
        self._writer.finish()
        self._file.flush()
        self._flushed = sum(self._counts.values())

    def _rosbag2_metadata_yaml(self) -> str:
        """The bag metadata rosbag2 (version 9) stores in ``serialized_metadata``."""
        first, last = self._log_time_range or (0, 0)
        duration = {"nanoseconds": last - first}
        start = {"nanoseconds_since_epoch": first}
        total = sum(self._counts.values())
        topics = [
            {"topic_metadata": {"name": topic, "type": type_name, "serialization_format": MESSAGE_ENCODING,
                                "offered_qos_profiles": yaml.safe_load(qos_yaml) or [],
                                "type_description_hash": digest},
             "message_count": self._counts[topic]}
            for topic, type_name, qos_yaml, digest in self._channels.values()
        ]
        metadata = {
            "version": ROSBAG2_METADATA_VERSION,
            "storage_identifier": "mcap",
            "relative_file_paths": [self.path.name],
            "duration": duration,
            "starting_time": start,
            "message_count": total,
            "topics_with_message_count": topics,
            "compression_format": "",
            "compression_mode": "",
            "files": [{"path": self.path.name, "starting_time": start, "duration": duration, "message_count": total}],
            "custom_data": {},
            "ros_distro": ROS_DISTRO,
        }
        return yaml.safe_dump(metadata, sort_keys=False, default_flow_style=False).strip()

    def _check_writable(self) -> None:
        if self._closed:
            raise ValueError(f"{self.path} is closed")
        if self.failure is not None:
            raise self.failure

    def _guarded(self, action):
        """Run a write with the lock held; the first OSError becomes the writer's failure."""
        try:
            return action()
        except OSError as error:
            self._fail(WriteFailure(f"cannot write {self.path}: {error.strerror or error}"))
            raise self.failure from None

    def _fail(self, failure: WriteFailure) -> None:
        if self.failure is not None:
            return
        self.failure = failure
        if self._on_failure is not None:
            self._on_failure(failure)

    def _flush_and_check(self) -> None:
        self._writer.flush()
        try:
            on_disk = os.stat(self.path)
        except FileNotFoundError:
            on_disk = None
        if on_disk is None or (on_disk.st_dev, on_disk.st_ino) != (self._identity.st_dev, self._identity.st_ino):
            self._flushed = 0
            raise OSError(0, f"the file was removed or replaced while recording (is {self.path.parent} still there?)")
        self._flushed = sum(self._counts.values())

    def _flush_periodically(self, period_s: float) -> None:
        while not self._stop_flushing.wait(period_s):
            with self._lock:
                if self.failure is not None:
                    return
                try:
                    self._guarded(self._flush_and_check)
                except WriteFailure:
                    return
