"""MCAP logger node: records every topic of the message contract, in every namespace.

``ros2 run nni_msgs_adapter mcap_logger --ros-args -p output_path:=run.mcap``

Once a second (and at start) it looks at the ROS graph for topics whose last
name component(s) match the contract (``pmu``, ``battery/command``, ...) under
any namespace, plus ``/clock``, and subscribes to each in raw (serialized) form,
so nothing is deserialised on the way to disk, with the contract's QoS and a
history of ``contract.RECORDER_DEPTH`` (a logger that falls behind catches up
instead of losing samples). Each message is written with log_time = receive
time and publish_time = its header stamp (read from the first eight CDR bytes:
every contract type starts with a builtin_interfaces/Time). The channel's
``offered_qos_profiles`` are the QoS of the publishers seen on the graph, so
``ros2 bag play`` offers the same QoS.

The writer closes a chunk and flushes the file every ``flush_period_s`` (default
0.5 s): after SIGKILL the file is readable up to the last flush, so at most the
last ``flush_period_s`` of messages are lost. SIGINT/SIGTERM finish the file
(summary and indexes) and print the per-topic counts as one JSON line.
"""

from __future__ import annotations

import json
import struct
import sys
from datetime import datetime
from pathlib import Path

from rclpy.node import Node

from nni_msgs_adapter import contract
from nni_msgs_adapter.mcap_io import OfferedQos, RecordingError, Ros2McapWriter, qos_profiles_yaml
from nni_msgs_adapter.node_main import run_node
from nni_msgs_adapter.ros_params import Spec, load_defaults, current_values, declare

DEFAULTS = load_defaults("nni_msgs_adapter", "mcap_logger.yaml", "mcap_logger")

PARAMETERS = (
    Spec("output_path", DEFAULTS["output_path"], "MCAP file to write; empty: nni_<date>_<time>.mcap in the working directory.",
         read_only=True),
    Spec("flush_period_s", DEFAULTS["flush_period_s"], "Longest time a received message waits before it is in the file, s.",
         0.01, 10.0, read_only=True),
    Spec("discovery_period_s", DEFAULTS["discovery_period_s"], "How often the graph is scanned for new topics, s.", 0.05, 60.0,
         read_only=True),
)

#: Prefix of the JSON line with per-topic counts printed at exit.
COUNTS_PREFIX = "mcap_logger counts: "

_STAMP = struct.Struct("<iI")  # builtin_interfaces/Time in little-endian CDR


def header_stamp_ns(cdr: bytes) -> int:
    """The leading builtin_interfaces/Time of a contract message, ns; 0 if unreadable."""
    if len(cdr) < 12 or cdr[1] != 0x01:  # encapsulation: CDR little-endian
        return 0
    sec, nanosec = _STAMP.unpack_from(cdr, 4)
    return sec * 1_000_000_000 + nanosec


def contract_topic_of(topic: str) -> str | None:
    """The contract topic a fully qualified name instantiates (``/gen1/pmu`` -> ``pmu``), or None."""
    if topic == contract.TOPIC_CLOCK:
        return topic
    for name in contract.TOPICS:
        if not name.startswith("/") and topic.endswith("/" + name):
            return name
    return None


class McapLogger(Node):
    """Subscribes to the contract's topics as they appear and writes them to one MCAP file."""

    def __init__(self, **kwargs):
        super().__init__("mcap_logger", **kwargs)
        declare(self, PARAMETERS)
        values = current_values(self, PARAMETERS)
        path = Path(values["output_path"] or datetime.now().strftime("nni_%Y%m%d_%H%M%S.mcap"))
        if not path.parent.is_dir():
            raise ValueError(f"output folder {path.parent} does not exist")
        self.path = path
        self._writer = Ros2McapWriter(path, flush_period_s=values["flush_period_s"])
        self._recorded: dict[str, object] = {}
        self._scan_graph()
        self.create_timer(values["discovery_period_s"], self._scan_graph)
        self.get_logger().info(f"recording to {path}")

    def _scan_graph(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            if topic in self._recorded:
                continue
            name = contract_topic_of(topic)
            if name is None:
                continue
            type_name = contract.TOPICS[name][0]
            if type_name not in types:
                continue
            offered = [OfferedQos.from_rclpy(info.qos_profile) for info in self.get_publishers_info_by_topic(topic)]
            if not offered:
                continue  # only subscribers so far; the publishers' QoS is what replay must offer
            try:
                channel = self._writer.add_channel(topic, type_name, qos_profiles_yaml(offered))
            except RecordingError as exc:
                self.get_logger().error(f"not recording {topic}: {exc}")
                self._recorded[topic] = None
                continue
            msg_class, _, qos = contract.recorder_endpoint(name)
            self._recorded[topic] = self.create_subscription(
                msg_class, topic, self._writer_for(channel), qos, raw=True)

    def _writer_for(self, channel: int):
        clock = self.get_clock()
        writer = self._writer

        def write(cdr: bytes) -> None:
            writer.write(channel, cdr, clock.now().nanoseconds, header_stamp_ns(cdr))

        return write

    def close(self) -> None:
        """Finish the file (summary, indexes) and print the per-topic counts."""
        self._writer.close()
        counts = self._writer.counts
        print(COUNTS_PREFIX + json.dumps({"path": str(self.path), "counts": counts}), flush=True)


def main(args=None) -> int:
    """``ros2 run nni_msgs_adapter mcap_logger``."""
    return run_node(McapLogger, args, prog="mcap_logger")


if __name__ == "__main__":
    sys.exit(main())
