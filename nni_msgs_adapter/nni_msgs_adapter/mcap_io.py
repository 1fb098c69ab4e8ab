"""ROS 2 (Jazzy) MCAP recordings: write them as rosbag2 does, read them back, recover killed ones.

A file written here is what ``ros2 bag record -s mcap`` (rosbag2 0.26, Jazzy) writes for the
same topics: profile ``ros2``; one schema per message type, named by the full type
(``sensor_msgs/msg/JointState``), encoding ``ros2msg``, holding the type's ``.msg`` text with all
its dependencies concatenated the way rosbag2's ``LocalMessageDefinitionSource`` does; one
channel per topic with message encoding ``cdr`` and the channel metadata ``offered_qos_profiles``
(YAML, policies as names, metadata version 9) and ``topic_type_hash`` (RIHS01); ``log_time`` in
nanoseconds since the epoch; a summary with chunk and message indexes and statistics.

The writer closes the current chunk and flushes the file at least once every
``flush_period_s`` seconds, so a recorder killed with SIGKILL leaves a file whose complete chunks
:func:`read_messages` still reads: every message flushed before the kill is recovered.

Nothing here imports rclpy at module level: :func:`deserialize`, :func:`serialize` and
:meth:`OfferedQos.to_rclpy` import it when called.
"""

from __future__ import annotations

import functools
import importlib
import io
import json
import os
import re
import struct
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Iterable, Iterator, NamedTuple

import yaml
from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Header, Message, Schema
from mcap.stream_reader import CRCValidationError, StreamReader
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer
from zstandard import ZstdError

__all__ = [
    "OfferedQos",
    "RecordedMessage",
    "RecordingError",
    "Ros2McapWriter",
    "deserialize",
    "message_class",
    "message_definition",
    "parse_qos_profiles_yaml",
    "qos_profiles_yaml",
    "read_messages",
    "serialize",
]

PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
QOS_METADATA_KEY = "offered_qos_profiles"
TYPE_HASH_METADATA_KEY = "topic_type_hash"

MCAP_MAGIC = b"\x89MCAP0\r\n"
# Every MCAP record starts with a one-byte opcode and an eight-byte little-endian body length.
_RECORD_PREFIX = struct.Struct("<BQ")
# A Footer body is summary_start (u64), summary_offset_start (u64) and summary_crc (u32).
_FOOTER_BODY_LENGTH = 8 + 8 + 4
_FOOTER_PREFIX = _RECORD_PREFIX.pack(Opcode.FOOTER, _FOOTER_BODY_LENGTH)
_FOOTER_AND_MAGIC_LENGTH = _RECORD_PREFIX.size + _FOOTER_BODY_LENGTH + len(MCAP_MAGIC)
# What parsing or decompressing a damaged record raises in the mcap library.
_CORRUPT_DATA_ERRORS = (McapError, CRCValidationError, ZstdError, struct.error, UnicodeDecodeError)


class RecordingError(ValueError):
    """A recording, message type or QoS description that cannot be used, with a one-line reason."""


# --------------------------------------------------------------------------------------------
# Message types and definitions
# --------------------------------------------------------------------------------------------

# rosbag2_cpp LocalMessageDefinitionSource: field types of a .msg file ("pkg/Type" in
# "pkg/Type[] name"). re.ASCII gives the byte-wise \s of the C++ std::regex it mirrors.
_MSG_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+", re.ASCII)
_PRIMITIVE_TYPES = frozenset(
    {
        "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
        "int32", "uint32", "int64", "uint64", "string",
    }
)  # fmt: skip
_DEFINITION_SEPARATOR = "=" * 80
_ROS_NAME = r"[a-zA-Z][a-zA-Z0-9_]*"
_TYPE_NAME = re.compile(rf"({_ROS_NAME})/(?:({_ROS_NAME})/)?({_ROS_NAME})")
_AMENT_PACKAGE_INDEX = Path("share", "ament_index", "resource_index", "packages")


class _TypeName(NamedTuple):
    package: str
    namespace: str
    name: str

    @property
    def full(self) -> str:
        return f"{self.package}/{self.namespace}/{self.name}"


def _parse_type_name(type_name: str) -> _TypeName:
    """Split ``pkg/Type`` or ``pkg/ns/Type`` (namespace defaults to ``msg``), as rosbag2 does."""
    match = _TYPE_NAME.fullmatch(type_name)
    if match is None:
        raise RecordingError(
            f"unknown message type {type_name!r}: expected a name like sensor_msgs/msg/JointState"
        )
    package, namespace, name = match.groups()
    return _TypeName(package, namespace or "msg", name)


def _package_share_directory(package: str, type_name: str) -> Path:
    """The share directory of *package*: the ament index, or ``sys.prefix`` (a pip venv)."""
    if os.environ.get("AMENT_PREFIX_PATH"):
        from ament_index_python.packages import (
            PackageNotFoundError,
            get_package_share_directory,
        )

        try:
            return Path(get_package_share_directory(package))
        except PackageNotFoundError:
            where = "AMENT_PREFIX_PATH"
    else:
        prefix = Path(sys.prefix)
        if (prefix / _AMENT_PACKAGE_INDEX / package).is_file():
            return prefix / "share" / package
        where = f"the ament index of {prefix} (AMENT_PREFIX_PATH is unset)"
    raise RecordingError(
        f"unknown message type {type_name!r}: package {package!r} is not in {where}"
    )


def _interface_file(type_name: str, suffix: str) -> Path:
    parsed = _parse_type_name(type_name)
    share = _package_share_directory(parsed.package, type_name)
    return share / parsed.namespace / f"{parsed.name}{suffix}"


@functools.cache
def _msg_text(type_name: str) -> str:
    """The verbatim text of the ``.msg`` file of *type_name* (line endings untouched)."""
    path = _interface_file(type_name, ".msg")
    try:
        with path.open(encoding="utf-8", newline="") as msg_file:
            return msg_file.read()
    except FileNotFoundError:
        raise RecordingError(f"unknown message type {type_name!r}: no {path}") from None


def _msg_dependencies(text: str, package: str) -> list[str]:
    """Non-primitive field types of a ``.msg`` text, sorted as rosbag2's std::set orders them."""
    dependencies = set()
    for match in _MSG_FIELD_TYPE.finditer(text):
        field_type = match.group(1)
        if field_type in _PRIMITIVE_TYPES:
            continue
        dependencies.add(field_type if "/" in field_type else f"{package}/{field_type}")
    return sorted(dependencies)


@functools.cache
def message_definition(type_name: str) -> str:
    """The ``ros2msg`` schema text of a message type, dependencies included, as rosbag2 writes it.

    The type's own ``.msg`` text comes first; then, depth-first and in sorted order at each
    level, every dependency not yet written, each preceded by a newline, a line of 80 ``=`` and
    a line ``MSG: <type as named in the field>`` (for example ``MSG: std_msgs/Header``). This is
    ``rosbag2_cpp::LocalMessageDefinitionSource::get_full_text`` of Jazzy, and what
    mcap-ros2-support and rosbags parse.

    Parameters
    ----------
    type_name : str
        Full type name such as ``"sensor_msgs/msg/JointState"`` (``"pkg/Type"`` is also
        accepted, as by rosbag2).

    Returns
    -------
    str
        The concatenated definition. Results are cached per type name.

    Raises
    ------
    RecordingError
        If the name is malformed, its package is not installed or it has no ``.msg`` file.
    """
    written: set[str] = set()

    def definition_with_dependencies(name: str) -> str:
        text = _msg_text(name)
        parts = [text]
        for dependency in _msg_dependencies(text, _parse_type_name(name).package):
            if dependency not in written:
                written.add(dependency)
                parts.append(f"\n{_DEFINITION_SEPARATOR}\nMSG: {dependency}\n")
                parts.append(definition_with_dependencies(dependency))
        return "".join(parts)

    return definition_with_dependencies(type_name)


@functools.cache
def _type_description_hash(type_name: str) -> str:
    """The RIHS01 type hash that rosidl generated for *type_name*, or ``""`` if there is none."""
    full_name = _parse_type_name(type_name).full
    try:
        description = json.loads(_interface_file(type_name, ".json").read_text(encoding="utf-8"))
    except FileNotFoundError:
        return ""
    for entry in description.get("type_hashes", []):
        if entry.get("type_name") == full_name:
            return entry["hash_string"]
    return ""


@functools.cache
def message_class(type_name: str) -> type:
    """The generated Python class of a message type (what rosidl_runtime_py's get_message does).

    Parameters
    ----------
    type_name : str
        Full type name such as ``"sensor_msgs/msg/JointState"``.

    Returns
    -------
    type
        The message class, for example ``sensor_msgs.msg.JointState``.

    Raises
    ------
    RecordingError
        If the name is malformed or no such class can be imported.
    """
    parsed = _parse_type_name(type_name)
    module_name = f"{parsed.package}.{parsed.namespace}"
    try:
        module = importlib.import_module(module_name)
    except ImportError:
        raise RecordingError(
            f"unknown message type {type_name!r}: cannot import {module_name}"
        ) from None
    try:
        return getattr(module, parsed.name)
    except AttributeError:
        raise RecordingError(
            f"unknown message type {type_name!r}: {module_name} has no {parsed.name}"
        ) from None


def deserialize(type_name: str, cdr_bytes: bytes) -> Any:
    """Decode CDR bytes into a message of *type_name* with ``rclpy.serialization``.

    Parameters
    ----------
    type_name : str
        Full type name such as ``"sensor_msgs/msg/JointState"``.
    cdr_bytes : bytes
        Serialized message, CDR encapsulation header included.

    Returns
    -------
    object
        An instance of :func:`message_class` of *type_name*.

    Raises
    ------
    RecordingError
        If the type is unknown or the bytes are not a CDR message of that type.
    """
    from rclpy.serialization import deserialize_message

    cls = message_class(type_name)
    try:
        return deserialize_message(cdr_bytes, cls)
    except RuntimeError as error:
        raise RecordingError(f"bytes are not a CDR {type_name}: {error}") from None


def serialize(message: Any) -> bytes:
    """Encode a ROS message object as CDR bytes with ``rclpy.serialization``.

    Parameters
    ----------
    message : object
        An instance of a generated ROS message class.

    Returns
    -------
    bytes
        The serialized message, as a publisher sends it and rosbag2 stores it.
    """
    from rclpy.serialization import serialize_message

    return serialize_message(message)


# --------------------------------------------------------------------------------------------
# QoS profiles
# --------------------------------------------------------------------------------------------

# rmw_qos_*_policy_to_str (rmw, Jazzy), with rosbag2's "unknown" for the UNKNOWN values. The
# integers are the rmw enum values, which are also rclpy's QoS*Policy values.
_POLICY_NAMES: dict[str, dict[int, str]] = {
    "history": {0: "system_default", 1: "keep_last", 2: "keep_all", 3: "unknown"},
    "reliability": {
        0: "system_default", 1: "reliable", 2: "best_effort", 3: "unknown", 4: "best_available",
    },
    "durability": {
        0: "system_default", 1: "transient_local", 2: "volatile", 3: "unknown",
        4: "best_available",
    },
    "liveliness": {
        0: "system_default", 1: "automatic", 3: "manual_by_topic", 4: "unknown",
        5: "best_available",
    },
}  # fmt: skip
_POLICY_VALUES = {
    policy: {name: value for value, name in names.items()}
    for policy, names in _POLICY_NAMES.items()
}
_NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class OfferedQos:
    """One offered QoS profile as rosbag2 records it; durations in nanoseconds.

    Policies are the rmw enum integers (equal to rclpy's ``QoS*Policy`` values); a zero
    duration means the rmw default (unspecified).

    Attributes
    ----------
    history, depth, reliability, durability, liveliness : int
        QoS policies (``depth`` counts messages).
    deadline_ns, lifespan_ns, liveliness_lease_duration_ns : int
        Durations in nanoseconds.
    avoid_ros_namespace_conventions : bool
        The rmw flag of the same name.
    """

    history: int = 1
    depth: int = 10
    reliability: int = 1
    durability: int = 2
    deadline_ns: int = 0
    lifespan_ns: int = 0
    liveliness: int = 0
    liveliness_lease_duration_ns: int = 0
    avoid_ros_namespace_conventions: bool = False

    @classmethod
    def from_rclpy(cls, profile: Any) -> OfferedQos:
        """Copy an ``rclpy.qos.QoSProfile`` (policies as integers, durations in nanoseconds)."""
        return cls(
            history=int(profile.history),
            depth=int(profile.depth),
            reliability=int(profile.reliability),
            durability=int(profile.durability),
            deadline_ns=profile.deadline.nanoseconds,
            lifespan_ns=profile.lifespan.nanoseconds,
            liveliness=int(profile.liveliness),
            liveliness_lease_duration_ns=profile.liveliness_lease_duration.nanoseconds,
            avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
        )

    def to_rclpy(self) -> Any:
        """The equivalent ``rclpy.qos.QoSProfile`` (imports rclpy)."""
        from rclpy.duration import Duration
        from rclpy.qos import (
            DurabilityPolicy,
            HistoryPolicy,
            LivelinessPolicy,
            QoSProfile,
            ReliabilityPolicy,
        )

        return QoSProfile(
            history=HistoryPolicy(self.history),
            depth=self.depth,
            reliability=ReliabilityPolicy(self.reliability),
            durability=DurabilityPolicy(self.durability),
            deadline=Duration(nanoseconds=self.deadline_ns),
            lifespan=Duration(nanoseconds=self.lifespan_ns),
            liveliness=LivelinessPolicy(self.liveliness),
            liveliness_lease_duration=Duration(nanoseconds=self.liveliness_lease_duration_ns),
            avoid_ros_namespace_conventions=self.avoid_ros_namespace_conventions,
        )


def _policy_name(policy: str, value: int) -> str:
    try:
        return _POLICY_NAMES[policy][value]
    except KeyError:
        raise ValueError(f"{value} is not an rmw {policy} policy") from None


def _duration_yaml(key: str, nanoseconds: int) -> list[str]:
    seconds, remainder = divmod(nanoseconds, _NS_PER_S)
    return [f"  {key}:", f"    sec: {seconds}", f"    nsec: {remainder}"]


def qos_profiles_yaml(profiles: Iterable[Any]) -> str:
    """The ``offered_qos_profiles`` channel metadata, byte for byte as rosbag2 (Jazzy) writes it.

    rosbag2 0.26 serializes with yaml-cpp (``rosbag2_storage::serialize_rclcpp_qos_vector``,
    metadata version 9): a block list of maps with keys in the order below, policies as rmw
    names, durations as ``sec``/``nsec`` maps, no trailing newline::

        - history: keep_last
          depth: 10
          reliability: reliable
          durability: volatile
          deadline:
            sec: 0
            nsec: 0
          lifespan:
            sec: 0
            nsec: 0
          liveliness: system_default
          liveliness_lease_duration:
            sec: 0
            nsec: 0
          avoid_ros_namespace_conventions: false

    Parameters
    ----------
    profiles : iterable of rclpy.qos.QoSProfile or OfferedQos
        The profiles offered by the topic's publishers.

    Returns
    -------
    str
        The YAML text; ``"[]"`` for no profiles (yaml-cpp's empty sequence).
    """
    lines: list[str] = []
    for profile in profiles:
        qos = profile if isinstance(profile, OfferedQos) else OfferedQos.from_rclpy(profile)
        lines += [
            f"- history: {_policy_name('history', qos.history)}",
            f"  depth: {qos.depth}",
            f"  reliability: {_policy_name('reliability', qos.reliability)}",
            f"  durability: {_policy_name('durability', qos.durability)}",
            *_duration_yaml("deadline", qos.deadline_ns),
            *_duration_yaml("lifespan", qos.lifespan_ns),
            f"  liveliness: {_policy_name('liveliness', qos.liveliness)}",
            *_duration_yaml("liveliness_lease_duration", qos.liveliness_lease_duration_ns),
            f"  avoid_ros_namespace_conventions: {str(qos.avoid_ros_namespace_conventions).lower()}",
        ]
    return "\n".join(lines) if lines else "[]"


def _parse_policy(policy: str, value: Any) -> int:
    """A policy from its rmw name (metadata v9) or its integer (metadata v8 and older)."""
    if isinstance(value, int) and not isinstance(value, bool):
        if value in _POLICY_NAMES[policy]:
            return value
    elif isinstance(value, str) and value in _POLICY_VALUES[policy]:
        return _POLICY_VALUES[policy][value]
    raise RecordingError(f"offered_qos_profiles: {value!r} is not a {policy} policy")


def _parse_duration(key: str, value: Any) -> int:
    if not isinstance(value, dict) or not {"sec", "nsec"} <= value.keys():
        raise RecordingError(f"offered_qos_profiles: {key} is not a map with sec and nsec")
    return int(value["sec"]) * _NS_PER_S + int(value["nsec"])


def parse_qos_profiles_yaml(text: str) -> list[OfferedQos]:
    """Parse ``offered_qos_profiles`` metadata back into profiles.

    Accepts what rosbag2 of any distribution wrote: policies as names (Jazzy, metadata
    version 9) or as integers (Humble and older); an empty string means no profiles.

    Parameters
    ----------
    text : str
        The channel metadata value.

    Returns
    -------
    list of OfferedQos
        One entry per recorded publisher profile.

    Raises
    ------
    RecordingError
        If the text is not a YAML list of complete QoS maps.
    """
    try:
        entries = yaml.safe_load(text) if text.strip() else []
    except yaml.YAMLError as error:
        reason = str(error).splitlines()[0]
        raise RecordingError(f"offered_qos_profiles is not YAML: {reason}") from None
    if not isinstance(entries, list):
        raise RecordingError("offered_qos_profiles is not a YAML list")
    profiles = []
    for entry in entries:
        if not isinstance(entry, dict):
            raise RecordingError("offered_qos_profiles: an entry is not a map")
        try:
            profiles.append(
                OfferedQos(
                    history=_parse_policy("history", entry["history"]),
                    depth=int(entry["depth"]),
                    reliability=_parse_policy("reliability", entry["reliability"]),
                    durability=_parse_policy("durability", entry["durability"]),
                    deadline_ns=_parse_duration("deadline", entry["deadline"]),
                    lifespan_ns=_parse_duration("lifespan", entry["lifespan"]),
                    liveliness=_parse_policy("liveliness", entry["liveliness"]),
                    liveliness_lease_duration_ns=_parse_duration(
                        "liveliness_lease_duration", entry["liveliness_lease_duration"]
                    ),
                    avoid_ros_namespace_conventions=bool(
                        entry["avoid_ros_namespace_conventions"]
                    ),
                )
            )
        except KeyError as missing:
            raise RecordingError(f"offered_qos_profiles: an entry has no {missing}") from None
    return profiles


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------


class Ros2McapWriter:
    """Write a rosbag2-compatible MCAP file that survives being killed.

    Messages are buffered in a zstd-compressed chunk; a background thread closes the chunk
    and flushes the file every *flush_period_s* seconds (a chunk also closes when it exceeds
    1 MiB). After SIGKILL the file lacks its summary but :func:`read_messages` recovers every
    message flushed before the kill. :meth:`close` (or leaving the ``with`` block) writes the
    summary: schemas, channels, statistics, chunk indexes (message indexes follow each chunk).

    All methods are thread-safe.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mcap`` file to create (replaced if it exists).
    flush_period_s : float, optional
        Longest time, in seconds, that a written message waits before it is in the file.

    Examples
    --------
    >>> with Ros2McapWriter("run.mcap") as writer:  # doctest: +SKIP
    ...     joints = writer.add_channel(
    ...         "/pmu", "sensor_msgs/msg/JointState", qos_profiles_yaml([OfferedQos()]))
    ...     writer.write(joints, serialize(msg), log_time_ns, publish_time_ns)
    """

    def __init__(self, path: str | os.PathLike[str], *, flush_period_s: float = 1.0) -> None:
        if not flush_period_s > 0:
            raise ValueError(f"flush_period_s must be positive, not {flush_period_s}")
        self.path = Path(path)
        self._lock = threading.Lock()
        self._file = self.path.open("wb")
        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library=f"nni_msgs_adapter {LIBRARY_IDENTIFIER}")
        self._writer.flush()
        self._schema_ids: dict[str, int] = {}
        self._channels: dict[int, tuple[str, str]] = {}  # channel id -> (topic, type name)
        self._channel_ids: dict[str, int] = {}  # topic -> channel id
        self._counts: dict[str, int] = {}
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

    def add_channel(self, topic: str, type_name: str, qos_yaml: str) -> int:
        """Register a topic; its type's schema is written the first time the type is seen.

        Parameters
        ----------
        topic : str
            Fully qualified topic name, e.g. ``"/gen1/pmu"``.
        type_name : str
            Full message type, e.g. ``"sensor_msgs/msg/JointState"``.
        qos_yaml : str
            The ``offered_qos_profiles`` metadata, normally from :func:`qos_profiles_yaml`.

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
        """
        if _parse_type_name(type_name).full != type_name:
            raise RecordingError(
                f"message type {type_name!r} is not a full name like sensor_msgs/msg/JointState"
            )
        definition = message_definition(type_name)
        type_hash = _type_description_hash(type_name)
        with self._lock:
            self._check_open()
            if topic in self._channel_ids:
                channel_id = self._channel_ids[topic]
                if self._channels[channel_id][1] != type_name:
                    raise ValueError(
                        f"topic {topic} is already recorded as {self._channels[channel_id][1]}"
                    )
                return channel_id
            if type_name not in self._schema_ids:
                self._schema_ids[type_name] = self._writer.register_schema(
                    name=type_name, encoding=SCHEMA_ENCODING, data=definition.encode()
                )
            channel_id = self._writer.register_channel(
                topic=topic,
                message_encoding=MESSAGE_ENCODING,
                schema_id=self._schema_ids[type_name],
                metadata={QOS_METADATA_KEY: qos_yaml, TYPE_HASH_METADATA_KEY: type_hash},
            )
            self._channels[channel_id] = (topic, type_name)
            self._channel_ids[topic] = channel_id
            self._counts[topic] = 0
            return channel_id

    def write(
        self, channel_id: int, cdr_bytes: bytes, log_time_ns: int, publish_time_ns: int
    ) -> None:
        """Append one serialized message.

        Parameters
        ----------
        channel_id : int
            An id returned by :meth:`add_channel`.
        cdr_bytes : bytes
            The message in CDR, as :func:`serialize` returns it.
        log_time_ns : int
            Reception time, nanoseconds since the epoch (rosbag2's ``recv_timestamp``).
        publish_time_ns : int
            Publication time, nanoseconds since the epoch (rosbag2's ``send_timestamp``).

        Raises
        ------
        ValueError
            If the channel id is unknown or the writer is closed.
        """
        with self._lock:
            self._check_open()
            if channel_id not in self._channels:
                raise ValueError(f"no channel with id {channel_id}")
            self._writer.add_message(
                channel_id=channel_id,
                log_time=log_time_ns,
                data=cdr_bytes,
                publish_time=publish_time_ns,
            )
            self._counts[self._channels[channel_id][0]] += 1

    def flush(self) -> None:
        """Close the current chunk (if it holds messages) and flush the file now."""
        with self._lock:
            self._check_open()
            self._writer.flush()

    def close(self) -> None:
        """Write the summary and close the file; later calls do nothing."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._stop_flushing.set()
        self._flusher.join()
        with self._lock:
            self._writer.finish()
            self._file.close()

    def _check_open(self) -> None:
        if self._closed:
            raise ValueError(f"{self.path} is closed")

    def _flush_periodically(self, period_s: float) -> None:
        while not self._stop_flushing.wait(period_s):
            with self._lock:
                self._writer.flush()


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


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
        The CDR message (decode with :func:`deserialize`).
    qos_yaml : str
        The channel's ``offered_qos_profiles`` (parse with :func:`parse_qos_profiles_yaml`).
    """

    topic: str
    type_name: str
    log_time_ns: int
    publish_time_ns: int
    cdr_bytes: bytes
    qos_yaml: str


def _recorded_message(
    path: Path, schema: Schema | None, channel: Channel, message: Message
) -> RecordedMessage:
    if schema is None:
        raise RecordingError(
            f"{path}: channel {channel.topic} has no schema, so its message type is unknown"
        )
    if channel.message_encoding != MESSAGE_ENCODING:
        raise RecordingError(
            f"{path}: channel {channel.topic} has message encoding "
            f"{channel.message_encoding!r}, expected {MESSAGE_ENCODING!r}"
        )
    return RecordedMessage(
        topic=channel.topic,
        type_name=schema.name,
        log_time_ns=message.log_time,
        publish_time_ns=message.publish_time,
        cdr_bytes=bytes(message.data),
        qos_yaml=channel.metadata.get(QOS_METADATA_KEY, ""),
    )


def _check_header(path: Path) -> None:
    """Raise :class:`RecordingError` unless *path* starts with a complete ``ros2`` MCAP header."""
    try:
        with path.open("rb") as stream:
            size = os.fstat(stream.fileno()).st_size
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
            body = stream.read(length)
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such recording") from None
    except IsADirectoryError:
        raise RecordingError(f"{path}: is a directory, not an MCAP file") from None
    try:
        profile = Header.read(ReadDataStream(io.BytesIO(body))).profile
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


def _iter_indexed(path: Path, stream: IO[bytes]) -> Iterator[RecordedMessage]:
    stream.seek(0)
    reader = SeekingReader(stream, validate_crcs=True)
    for schema, channel, message in reader.iter_messages(log_time_order=True):
        yield _recorded_message(path, schema, channel, message)


def _iter_complete_records(path: Path, stream: IO[bytes], size: int) -> Iterator[RecordedMessage]:
    """Messages of every complete record of an unfinished file, in file order."""
    complete_length = _complete_records_end(stream, size)
    stream.seek(0)
    records = StreamReader(_PrefixStream(stream, complete_length), validate_crcs=True).records
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    recovered = 0
    try:
        for record in records:
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                if record.channel_id not in channels:
                    raise RecordingError(
                        f"{path}: message on channel {record.channel_id}, "
                        "which is not defined before it"
                    )
                channel = channels[record.channel_id]
                yield _recorded_message(path, schemas.get(channel.schema_id), channel, record)
                recovered += 1
    except EndOfFile:
        pass  # the end of the complete records: the file was cut after them
    if recovered == 0:
        raise RecordingError(
            f"{path}: unfinished recording (no summary) with no complete message: "
            "cut before its first flush"
        )


def _iter_messages(path: Path) -> Iterator[RecordedMessage]:
    with path.open("rb") as stream:
        size = os.fstat(stream.fileno()).st_size
        try:
            if _has_footer(stream, size):
                yield from _iter_indexed(path, stream)
            else:
                yield from _iter_complete_records(path, stream, size)
        except _CORRUPT_DATA_ERRORS as error:
            raise RecordingError(f"{path}: corrupt MCAP data: {error}") from None


def read_messages(path: str | os.PathLike[str]) -> Iterator[RecordedMessage]:
    """Iterate over the messages of a ROS 2 MCAP recording, finished or cut short.

    A finished file (footer present) is read through its index, in log-time order. A file
    without a footer, left by a recorder killed mid-write, is read sequentially up to its last
    complete record: every message of every chunk that reached the file is returned, in file
    order, and the truncated tail is ignored. For files from :class:`Ros2McapWriter` that is
    every message flushed before the kill.

    The header is checked before this returns; the remaining problems surface while iterating.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mcap`` file.

    Returns
    -------
    iterator of RecordedMessage
        ``(topic, type_name, log_time_ns, publish_time_ns, cdr_bytes, qos_yaml)`` tuples.

    Raises
    ------
    RecordingError
        The file is missing, empty, not MCAP (bad magic), cut inside its header, not of the
        ``ros2`` profile, has a channel without schema or not in CDR, is corrupt (CRC), or is
        unfinished with no complete message.
    """
    recording = Path(path)
    _check_header(recording)
    return _iter_messages(recording)
