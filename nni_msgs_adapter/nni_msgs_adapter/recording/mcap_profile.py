"""What a ROS 2 (Jazzy) MCAP holds about message types: schemas, type hashes, CDR.

A schema is named by the full type (``sensor_msgs/msg/JointState``), encoded ``ros2msg``, and
holds the type's ``.msg`` text with all its dependencies concatenated the way rosbag2's
``LocalMessageDefinitionSource`` does (:func:`message_definition`). This stays hand-written:
rosbags' ``generate_msgdef`` writes a normalised text without the comments of the ``.msg``
files, which is not what ``ros2 bag record`` writes (the test compares both with the shipped
recordings byte for byte). The channel's ``topic_type_hash`` (RIHS01) comes from rosbags,
computed from that same definition.

Nothing here imports rclpy at module level: :func:`deserialize` and :func:`serialize` import it
when called.
"""

from __future__ import annotations

import functools
import importlib
import os
import re
import sys
from pathlib import Path
from typing import Any, NamedTuple

from rosbags.typesys import Stores, get_types_from_msg, get_typestore

PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"


class RecordingError(ValueError):
    """A recording, message type or QoS description that cannot be used, with a one-line reason."""


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
def type_hash(type_name: str) -> str:
    """The RIHS01 type hash of *type_name* (``topic_type_hash``), as rosidl generates it.

    rosbags computes it from the definition this module writes (parsed back with
    ``get_types_from_msg``), so the hash always describes the schema in the file; it equals
    the ``hash_string`` of rosidl's ``<Type>.json`` for every installed type (tested).

    Raises
    ------
    RecordingError
        As :func:`message_definition`.
    """
    typestore = get_typestore(Stores.EMPTY)
    typestore.register(get_types_from_msg(message_definition(type_name), _parse_type_name(type_name).full))
    return typestore.hash_rihs01(_parse_type_name(type_name).full)


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
