"""MCAP logger node: records every topic of the message contract, in every namespace.

``ros2 run nni_msgs_adapter mcap_logger --ros-args -p output_path:=run.mcap``

Once a second (and at start) it looks at the ROS graph for topics that the contract's
one matcher (:func:`recording.split_topic`) knows: ``pmu``, ``battery/command``, ... under
any namespace, plus the absolute ``/clock`` and ``/diagnostics``; it subscribes to each in
raw (serialized) form, so nothing is deserialised on the way to disk, with the contract's QoS
and a history of ``contract.RECORDER_DEPTH`` (a logger that falls behind catches up instead of
losing samples). Each message is written with log_time = receive time (the logger's clock when
the callback runs) and publish_time = the DDS source timestamp, the sender's clock when it
wrote the sample, from the message info, as rosbag2 records them. rclpy's EventsExecutor, which
the other nodes spin, fails on a callback that asks for the message info (``SystemError: null
argument to internal routine``, rclpy 7.1 of Jazzy, measured), so the logger asks
:func:`node_main.run_node` for SingleThreadedExecutor (:attr:`McapLogger.needs_message_info`).
The channel's
``offered_qos_profiles`` are the QoS of the publishers seen on the graph, so ``ros2 bag play``
offers the same QoS.

With the run's key (``NNI_COMMAND_KEY_FILE``, as the plant and its controllers have it) the logger
checks the seal of every message on a sealed topic (:data:`contract.SEALS`: measurements, commands,
true and controller states) as its readers do, under that topic's key and in sequence; a message
whose seal does not verify (a rogue's, or a captured one sent again) is written apart, on
:data:`~nni_msgs_adapter.recording.runs.FOREIGN_PREFIX` and its topic (``/nni_foreign/pmu``), which
no reader takes for the loop's, and counted (``foreign`` in the counts line). ``/clock`` cannot
carry a seal in its type: a tick is recorded on ``/clock`` once a sealed measurement of the same stamp was (the
plant sends one tick per measurement, after it), once per stamp, and apart otherwise (every tick, when the
run's metadata says ``"mode": "realtime"``: the plant sends none then)
(:class:`~nni_msgs_adapter.recording.runs.ClockTicks`; a tick waits for its measurement, so it may be written a
little after messages received later, with its own receive time). ``/diagnostics`` has no seal and is recorded as
it comes. Without a key everything is recorded as it comes.

``run_metadata`` (a JSON object, e.g. what ``nni-demo`` ran) is written at start as the MCAP
metadata record ``nni_run``, each top-level key holding its value's JSON text. At the end the
writer adds rosbag2's own metadata record (``ros2 bag info`` shows "ROS Distro: jazzy").

The writer closes a chunk and flushes the file every ``flush_period_s`` (default 0.5 s): after
SIGKILL the file is readable up to the last flush, so at most the last ``flush_period_s`` of
messages are lost. SIGINT/SIGTERM finish the file (summary and indexes) and print the
per-topic counts as one JSON line. If the file cannot be written any more (a full disk, its
folder removed), the logger publishes an ERROR status on ``/diagnostics`` at once, stops, prints
one line saying what happened and how many messages the file keeps (read back), and exits 1; the file
stays readable as an incomplete recording up to its last flush.
"""

from __future__ import annotations

import functools
import json
import struct
import sys
from datetime import datetime
from pathlib import Path

from rclpy.node import Node
from rclpy.task import Future

from nni_msgs_adapter.ros import command_auth, contract
from nni_msgs_adapter.ros.defaults import logger_defaults
from nni_msgs_adapter.recording.mcap_io import (
    OfferedQos, RecordingError, Ros2McapWriter, WriteFailure, qos_profiles_yaml, read_recording,
)
from nni_msgs_adapter.ros.node_main import run_node
from nni_msgs_adapter.recording.runs import (FOREIGN_PREFIX, RUN_METADATA_NAME, ClockTicks, WriterMatches,
                                             new_loop_topics)
from nni_msgs_adapter.ros.ros_params import Spec, declared_values

@functools.cache
def parameters() -> tuple[Spec, ...]:
    """The logger's parameters, their defaults from ``config/mcap_logger.yaml`` (read once, on first use)."""
    defaults = logger_defaults()
    return (
        Spec("output_path", defaults["output_path"], "MCAP file to write; empty: nni_<date>_<time>.mcap in the working directory.",
             read_only=True),
        Spec("flush_period_s", defaults["flush_period_s"], "Longest time a received message waits before it is in the file, s.",
             0.01, 10.0, read_only=True),
        Spec("discovery_period_s", defaults["discovery_period_s"], "How often the graph is scanned for new topics, s.", 0.05, 60.0,
             read_only=True),
        Spec("run_metadata", defaults["run_metadata"], "The run's parameters, a JSON object, written as the MCAP metadata "
             f"record {RUN_METADATA_NAME!r} (each top-level key -> its JSON text); empty: none.", read_only=True),
    )


#: Prefix of the JSON line with per-topic counts printed at exit.
COUNTS_PREFIX = "mcap_logger counts: "
#: Logged (INFO) when a topic's subscription is made, the topic after it (then a ``runs.MATCHED_PREFIX`` line once
#: it has matched the topic's writers: what a launcher waits for).
SUBSCRIBED_PREFIX = "recording topic "
#: Exit status of a logger that could not write its file to the end.
EXIT_WRITE_FAILURE = 1
#: Most messages one callback writes from its topic's queue before it hands the executor back.
DRAIN_LIMIT = 100


_STAMP = struct.Struct("<iI")  # builtin_interfaces/Time in little-endian CDR


def header_stamp_ns(cdr: bytes) -> int:
    """The leading builtin_interfaces/Time of a contract message, ns; 0 if unreadable (every contract type starts with one)."""
    if len(cdr) < 12 or cdr[1] != 0x01:  # encapsulation: CDR little-endian
        return 0
    sec, nanosec = _STAMP.unpack_from(cdr, 4)
    return sec * 1_000_000_000 + nanosec


def run_metadata_record(text: str) -> dict[str, str] | None:
    """The ``nni_run`` record for a ``run_metadata`` parameter: key -> JSON text; None if empty.

    Raises
    ------
    ValueError
        If the text is not a JSON object.
    """
    if not text.strip():
        return None
    try:
        value = json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(f"run_metadata is not JSON: {error}") from None
    if not isinstance(value, dict):
        raise ValueError(f"run_metadata must be a JSON object, not {type(value).__name__}")
    return {key: json.dumps(item) for key, item in value.items()}


class McapLogger(Node):
    """Subscribes to the contract's topics as they appear and writes them to one MCAP file."""

    #: Its callbacks take the message info (publish time): node_main spins it on SingleThreadedExecutor.
    needs_message_info = True

    def __init__(self, **kwargs):
        super().__init__("mcap_logger", **kwargs)
        values = declared_values(self, parameters())
        self._values = values
        metadata = run_metadata_record(values["run_metadata"])
        path = Path(values["output_path"] or datetime.now().strftime("nni_%Y%m%d_%H%M%S.mcap"))
        if not path.parent.is_dir():
            raise ValueError(f"output folder {path.parent} does not exist")
        self.path = path
        self.done = Future()
        self._diag_pub = self.create_publisher(*contract.endpoint(contract.TOPIC_DIAGNOSTICS))
        self._writer = Ros2McapWriter(path, flush_period_s=values["flush_period_s"], on_failure=self._on_failure)
        if metadata is not None:
            self._writer.add_metadata(RUN_METADATA_NAME, metadata)
        self._recorded: dict[str, object] = {}
        self._matches = WriterMatches()
        self._key = command_auth.key_from_environment()
        #: topic -> messages written apart as not the loop's (their seals did not verify; /clock: no sealed
        #: measurement had the tick's stamp, :class:`~nni_msgs_adapter.recording.runs.ClockTicks`).
        self.foreign: dict[str, int] = {}
        # A realtime run's plant sends no tick (the demos say the mode in the run's metadata): every one is foreign.
        realtime = metadata is not None and metadata.get("mode") == json.dumps("realtime")
        self._ticks = ClockTicks(plant_ticks=not realtime) if self._key is not None else None
        self._put_tick = None  # the /clock channel's writer, once it records
        self._scan_graph()
        self.create_timer(values["discovery_period_s"], self._scan_graph)
        self.get_logger().info(f"recording to {path}")

    def effective_parameters(self) -> dict:
        """What the logger runs with, stated at start (node_main): also the sign, for a launcher's read-back, that
        it has read the run's key (the key is removed once every node has)."""
        return dict(self._values)

    @property
    def failure(self) -> WriteFailure | None:
        """Why the file could not be written to the end, or None."""
        return self._writer.failure

    def messages_in_file(self) -> int:
        """Messages the file holds now, read back (after a failure: what an incomplete file keeps)."""
        try:
            return len(read_recording(self.path).messages)
        except RecordingError:
            return 0

    def _scan_graph(self) -> None:
        if self.failure is not None:
            return
        for topic, name, publishers in new_loop_topics(self, self._recorded):
            type_name = contract.TOPICS[name][0]
            offered = [OfferedQos.from_rclpy(info.qos_profile) for info in publishers]  # what replay must offer
            try:
                channel = self._writer.add_channel(topic, type_name, qos_profiles_yaml(offered))
            except RecordingError as exc:
                self.get_logger().error(f"not recording {topic}: {exc}")
                self._recorded[topic] = None
                continue
            except WriteFailure:
                return
            msg_class, _, qos = contract.recorder_endpoint(name)
            self._recorded[topic] = self.create_subscription(
                msg_class, topic, self._writer_for(channel, topic, name, qos_profiles_yaml(offered)), qos, raw=True)
            self.get_logger().info(SUBSCRIBED_PREFIX + topic)
        for line in self._matches.new_lines(self, self._recorded):
            self.get_logger().info(line)

    def _writer_for(self, channel: int, topic: str, name: str, qos_yaml: str):
        """The callback of ``topic``: writes the message and those already queued behind it (``DRAIN_LIMIT`` in all).

        Draining the queue in one wake-up (``take_message`` on the subscription's handle, as the
        executor itself takes) spares SingleThreadedExecutor a wait-set rebuild per message: without
        it the logger fell behind a 1000 frames/s lockstep run under load and lost samples (measured).
        The limit hands the executor back now and then, so that the graph scan and the other
        topics are served while a topic streams.
        """
        clock = self.get_clock()
        writer = self._writer
        check = contract.SealCheck(self._key, topic, name)
        foreign = []  # the channel of the messages that are not the loop's, once one came

        def apart() -> int:
            if not foreign:
                foreign.append(writer.add_channel(FOREIGN_PREFIX + topic, contract.TOPICS[name][0], qos_yaml))
                self.get_logger().error(f"a message on {topic} is not the loop's (not sealed by this run's nodes"
                                        f"{'' if name != contract.TOPIC_CLOCK else ', or no sealed measurement has its stamp'}"
                                        f"): recorded apart on {FOREIGN_PREFIX + topic}")
            self.foreign[topic] = self.foreign.get(topic, 0) + 1
            return foreign[0]

        def put(message: tuple, loop: bool) -> None:
            received_ns, data, message_info = message
            writer.write(channel if loop else apart(), data, received_ns, message_info["source_timestamp"])

        # With the key, /clock's ticks wait in self._ticks for the sealed measurements that pmu topics feed it.
        ticks = self._ticks if name == contract.TOPIC_CLOCK else None
        measures = self._ticks if name == contract.TOPIC_PMU else None
        if ticks is not None:
            self._put_tick = put

        def record(message: tuple) -> None:
            data = message[1]
            if ticks is not None:
                decided = ticks.tick(header_stamp_ns(data), message)
            else:
                loop = check.loops(data)
                put(message, loop)
                decided = measures.measured(header_stamp_ns(data)) if loop and measures is not None else ()
            for tick, loop in decided:
                self._put_tick(tick, loop)

        def write(cdr: bytes, info: dict) -> None:
            subscription = self._recorded[topic]
            taken = [(clock.now().nanoseconds, cdr, info)]
            with subscription.handle:
                while len(taken) < DRAIN_LIMIT:
                    message = subscription.handle.take_message(subscription.msg_type, True)
                    if message is None:
                        break
                    taken.append((clock.now().nanoseconds, *message))
            for message in taken:
                if writer.failure is not None:
                    return  # reported once, at the failure; the node is stopping
                try:
                    record(message)
                except WriteFailure:
                    return  # on_failure has reported it

        return write

    def _on_failure(self, failure: WriteFailure) -> None:
        """First write failure (any thread): ERROR on /diagnostics at once, then stop the node."""
        self._diag_pub.publish(contract.diagnostics_message(
            self.get_clock().now().nanoseconds, "mcap_logger", "ERROR", str(failure),
            {"path": str(self.path), "messages_flushed": self._writer.flushed}, self.get_fully_qualified_name()))
        if not self.done.done():
            self.done.set_result(False)

    def close(self) -> None:
        """Finish the file (summary, indexes) and print the per-topic counts; after a failure only close it."""
        if self._ticks is not None and self._put_tick is not None and self.failure is None:
            try:
                for tick, loop in self._ticks.rest():
                    self._put_tick(tick, loop)
            except WriteFailure:
                pass  # on_failure has reported it
        self._writer.close()
        if self.failure is None:
            counts = {topic: n for topic, n in self._writer.counts.items() if not topic.startswith(FOREIGN_PREFIX + "/")}
            print(COUNTS_PREFIX + json.dumps({"path": str(self.path), "counts": counts, "foreign": self.foreign}),
                  flush=True)


def main(args=None) -> int:
    """``ros2 run nni_msgs_adapter mcap_logger``: 0 when the file was finished, 1 after a write failure."""
    loggers = []

    def make_logger() -> McapLogger:
        loggers.append(McapLogger())
        return loggers[-1]

    status = run_node(make_logger, args, prog="mcap_logger")
    if status == 0 and loggers and loggers[0].failure is not None:
        logger = loggers[0]
        kept_count = logger.messages_in_file()
        kept = (f"{logger.path} is incomplete: it keeps the {kept_count} messages written before the failure"
                if kept_count else "nothing recorded is kept")
        print(f"mcap_logger: error: {logger.failure}; {kept}", file=sys.stderr, flush=True)
        return EXIT_WRITE_FAILURE
    return status


if __name__ == "__main__":
    sys.exit(main())
