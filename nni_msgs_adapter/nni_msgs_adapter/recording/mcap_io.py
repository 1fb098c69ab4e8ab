"""ROS 2 (Jazzy) MCAP recordings: the one import for writing, reading and recovering them.

The parts live in their own modules; this module gathers what the rest of the project uses:

* :mod:`mcap_profile`: schemas (message definitions as rosbag2 writes them), RIHS01 type
  hashes (from rosbags), message classes, CDR (de)serialization;
* :mod:`mcap_qos`: the ``offered_qos_profiles`` channel metadata;
* :mod:`mcap_writer`: the writer (channel metadata, timed flush, rosbag2 metadata, write
  failures detected);
* :mod:`mcap_reader`: the reader (regular files only, size caps, recovery of cut files,
  duplicate chunks, metadata records).
"""

from __future__ import annotations

from nni_msgs_adapter.recording.mcap_profile import (
    MESSAGE_ENCODING, PROFILE, SCHEMA_ENCODING, RecordingError, deserialize, message_class, message_definition,
    serialize, type_hash,
)
from nni_msgs_adapter.recording.mcap_qos import (
    QOS_METADATA_KEY, OfferedQos, describe_qos, parse_qos_profiles_yaml, qos_profiles_yaml,
)
from nni_msgs_adapter.recording.mcap_reader import (
    MAX_CHUNK_BYTES, MAX_RECORD_BYTES, MAX_TOTAL_BYTES, MCAP_MAGIC, RecordedMessage, Recording, read_messages,
    read_recording,
)
from nni_msgs_adapter.recording.mcap_writer import (
    ROS_DISTRO, TYPE_HASH_METADATA_KEY, Ros2McapWriter, WriteFailure,
)

__all__ = [
    "MAX_CHUNK_BYTES", "MAX_RECORD_BYTES", "MAX_TOTAL_BYTES", "MCAP_MAGIC", "MESSAGE_ENCODING", "PROFILE",
    "QOS_METADATA_KEY", "ROS_DISTRO", "SCHEMA_ENCODING", "TYPE_HASH_METADATA_KEY",
    "OfferedQos", "RecordedMessage", "Recording", "RecordingError", "Ros2McapWriter", "WriteFailure",
    "describe_qos", "deserialize", "message_class", "message_definition", "parse_qos_profiles_yaml", "qos_profiles_yaml",
    "read_messages", "read_recording", "serialize", "type_hash",
]
