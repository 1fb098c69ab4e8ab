"""Foxglove bridge node: the loop's topics, live, over the Foxglove WebSocket protocol (issue 34).

    ros2 run nni_msgs_adapter foxglove_bridge --ros-args -p address:=127.0.0.1:8765

What foxglove_bridge does for C++ ROS systems, for this loop's topics only: the node scans the graph as the
MCAP logger does (:func:`nni_msgs_adapter.recording.runs.new_loop_topics`: measurements, battery commands, plant and
controller states, the invariant set, ``/clock``, ``/diagnostics``, every generator's of a network) and offers
each on a Foxglove server (``foxglove-sdk``) as a channel of the same name, ``cdr`` messages with the
``ros2msg`` schema rosbag2 writes (:func:`nni_msgs_adapter.recording.mcap_profile.message_definition`), so that
Foxglove's panels decode them as they decode foxglove_bridge's. The bytes are passed on as they came, never
decoded. A channel ``/nni/run`` (JSON) says once a second which run is on (``run_label``: b, law, case, ...).
The run's verdict, once its launcher has judged the recording, comes on ``/nni/verdict`` (JSON): the launcher
writes it to ``verdict_file`` (one JSON object, written whole by a rename), the bridge sends it once, adds its
words to the label and logs ``streamed the verdict: <words>``.

With the run's key (``NNI_COMMAND_KEY_FILE``) every sealed topic is checked as the logger checks it
(:class:`nni_msgs_adapter.ros.contract.SealCheck`); what does not verify goes to ``/nni_foreign/<topic>``, so a
rogue's angle is never drawn as the machine's. Without a key everything is passed on as it comes.

Off the control path: a separate process with its own subscriptions (KEEP_LAST, as the logger's: a slow bridge
never holds a writer back), and the server queues at most ``backlog`` messages per client, dropping a slow
client's oldest (the SDK's ``message_backlog_size``); nothing is buffered without bound. The server listens on
loopback unless ``address`` names a host. Client messages the protocol does not allow (garbage, an unknown
channel, a huge frame) are the SDK's to refuse.

At exit one line ``foxglove_bridge counts: {"counts": {topic: n}, "foreign": {topic: n}}``.
"""

from __future__ import annotations

import functools
import json
import os
import sys
from pathlib import Path

import foxglove
from foxglove.websocket import ServerListener
from rclpy.node import Node

from nni_msgs_adapter.c37118.profile import address_text, parse_server_address
from nni_msgs_adapter.recording.mcap_profile import SCHEMA_ENCODING, message_definition
from nni_msgs_adapter.recording.runs import FOREIGN_PREFIX, WriterMatches, new_loop_topics
from nni_msgs_adapter.ros import command_auth, contract
from nni_msgs_adapter.ros.defaults import load_defaults
from nni_msgs_adapter.ros.node_main import run_node
from nni_msgs_adapter.ros.ros_params import Spec, declared_values

#: Logged (INFO) once a topic is offered, the topic after it (a launcher can wait for these, as for the logger's).
STREAMING_PREFIX = "streaming topic "
#: Logged (INFO) each time a client subscribes to a channel, the channel's topic after it (``nni-demo
#: --foxglove-wait`` holds a run's start until it reads one).
SUBSCRIBED_PREFIX = "a Foxglove client subscribed to "
#: Logged (INFO) once the server listens, its ws:// URL after it.
SERVING_TEXT = "foxglove bridge serving on"
#: Prefix of the JSON line with per-topic counts printed at exit.
COUNTS_PREFIX = "foxglove_bridge counts: "
#: The channel that says which run is on.
RUN_TOPIC = "/nni/run"
#: The channel of the run's verdict (once, when its launcher has judged the run).
VERDICT_TOPIC = "/nni/verdict"
#: Logged (INFO) once the verdict is sent, its words after it.
VERDICT_PREFIX = "streamed the verdict: "
_VERDICT_SCHEMA = {"type": "object", "title": "nni verdict", "properties": {
    "verdict": {"type": "string"}, "in_synchronism": {"type": "boolean"}, "compromised": {"type": "boolean"}},
    "required": ["verdict"], "additionalProperties": True}
_RUN_SCHEMA = {"type": "object", "title": "nni run", "properties": {"label": {"type": "string"}},
               "additionalProperties": True}


@functools.cache
def parameters() -> tuple[Spec, ...]:
    """The bridge's parameters, their defaults from ``config/foxglove_bridge.yaml``."""
    defaults = load_defaults("nni_msgs_adapter", "foxglove_bridge.yaml", "foxglove_bridge")
    return (
        Spec("address", defaults["address"], "[HOST:]PORT of the Foxglove WebSocket server (loopback unless a host "
             "is named; port 0: a free one).", read_only=True),
        Spec("discovery_period_s", defaults["discovery_period_s"], "How often the graph is scanned for new topics, s.",
             0.05, 60.0, read_only=True),
        Spec("backlog", defaults["backlog"], "Messages queued per client; a slow client loses its oldest.", 16,
             1_000_000, read_only=True),
        Spec("nice", defaults["nice"], "Added to the process's nice value at start: the bridge yields the CPU to "
             "the loop's nodes (0: as they).", 0, 19, read_only=True),
        Spec("run_label", defaults["run_label"], f"The run on air, a JSON object, sent on {RUN_TOPIC} once a second.",
             read_only=True),
        Spec("verdict_file", defaults["verdict_file"], f"A file the launcher writes the run's verdict to (a JSON "
             f"object with a 'verdict' string), sent once on {VERDICT_TOPIC} when it appears (empty: none).",
             read_only=True),
    )


def json_object(text: str, what: str) -> dict:
    """``text`` (the launcher's: the run label, the verdict) as a dict; ValueError (one line) naming ``what`` if it
    is not a JSON object. An unlimited battery (Python's ``Infinity``) becomes the word ``"inf"``: what a client
    gets is strict JSON."""
    try:
        value = json.loads(text, parse_constant={"Infinity": "inf", "-Infinity": "-inf", "NaN": "nan"}.get)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{what} must be a JSON object: {exc}") from None
    if not isinstance(value, dict):
        raise ValueError(f"{what} must be a JSON object")
    return value


def run_label(text: str) -> dict:
    """The ``run_label`` parameter as a dict (empty: none); ValueError (one line) if it is not a JSON object."""
    return json_object(text, "run_label") if text else {}


def json_channel(topic: str, name: str, schema: dict) -> foxglove.Channel:
    """A Foxglove channel of JSON messages under a JSON Schema (the bridge's own: the run and its verdict)."""
    return foxglove.Channel(topic, message_encoding="json", schema=foxglove.Schema(
        name=name, encoding="jsonschema", data=json.dumps(schema).encode()))


def ros2_channel(topic: str, type_name: str) -> foxglove.Channel:
    """A Foxglove channel of a ROS 2 topic: CDR messages, the type's ``ros2msg`` schema (as foxglove_bridge's)."""
    schema = foxglove.Schema(name=type_name, encoding=SCHEMA_ENCODING, data=message_definition(type_name).encode())
    return foxglove.Channel(topic, schema=schema, message_encoding="cdr")


class _SubscriptionLog(ServerListener):
    """Logs each client subscription (the SDK calls this from its own thread; rclpy's logging is thread-safe)."""

    def __init__(self, logger):
        self._logger = logger

    def on_subscribe(self, client, channel) -> None:
        self._logger.info(SUBSCRIBED_PREFIX + channel.topic)


class FoxgloveBridge(Node):
    """Offers every loop topic it finds on a Foxglove WebSocket server, the rogue's apart."""

    def __init__(self, **kwargs):
        super().__init__("foxglove_bridge", **kwargs)
        self._values = values = declared_values(self, parameters())
        os.nice(values["nice"])  # a viewer yields the CPU to the loop (bench section 12)
        self._label = run_label(values["run_label"])
        host, port = parse_server_address(values["address"], what="a Foxglove server address")
        self._key = command_auth.key_from_environment()
        try:
            self._server = foxglove.start_server(name="nni", host=host, port=port,
                                                 message_backlog_size=int(values["backlog"]),
                                                 server_listener=_SubscriptionLog(self.get_logger()))
        except Exception as exc:  # the SDK raises its own error types (address in use, ...)
            raise ValueError(f"cannot serve Foxglove on {address_text(host, port)}: {exc}") from None
        self.url = f"ws://{address_text(host, self._server.port)}"
        self._run_channel = json_channel(RUN_TOPIC, "nni/Run", _RUN_SCHEMA)
        self._verdict_file = values["verdict_file"]
        self._verdict_channel = json_channel(VERDICT_TOPIC, "nni/Verdict", _VERDICT_SCHEMA) \
            if self._verdict_file else None
        self._streamed: dict[str, object] = {}
        self._matches = WriterMatches()
        self.counts: dict[str, int] = {}
        self.foreign: dict[str, int] = {}
        self._scan_graph()
        self.create_timer(values["discovery_period_s"], self._scan_graph)
        self.create_timer(1.0, self._send_label)
        self._send_label()
        self.get_logger().info(f"{SERVING_TEXT} {self.url}")

    def effective_parameters(self) -> dict:
        """What the bridge runs with (stated at start: a launcher's read-back also learns it has the key)."""
        return dict(self._values)

    def _send_label(self) -> None:
        self._run_channel.log({"label": ", ".join(f"{k} {v}" for k, v in self._label.items()), **self._label})

    def _send_verdict(self) -> None:
        """Once ``verdict_file`` exists: send it on /nni/verdict, put its words in the label (a file that is no
        JSON object with a 'verdict' string is named at ERROR once and not sent)."""
        if self._verdict_channel is None or not os.path.exists(self._verdict_file):
            return
        try:
            verdict = json_object(Path(self._verdict_file).read_text(encoding="utf-8"), "the verdict")
            if not isinstance(verdict.get("verdict"), str):
                raise ValueError("the verdict has no 'verdict' string")
        except (OSError, ValueError) as exc:
            self.get_logger().error(f"verdict_file {self._verdict_file}: {exc}; no verdict streamed")
        else:
            self._verdict_channel.log(verdict)
            self._label["verdict"] = verdict["verdict"]
            self._send_label()
            self.get_logger().info(VERDICT_PREFIX + verdict["verdict"])
        self._verdict_channel = None

    def _scan_graph(self) -> None:
        self._send_verdict()
        for topic, name, _ in new_loop_topics(self, self._streamed):
            msg_class, _, qos = contract.recorder_endpoint(name)
            self._streamed[topic] = self.create_subscription(msg_class, topic, self._forward(topic, name), qos,
                                                             raw=True)
            self.get_logger().info(STREAMING_PREFIX + topic)
        for line in self._matches.new_lines(self, self._streamed):
            self.get_logger().info(line)

    def _forward(self, topic: str, name: str):
        type_name = contract.TOPICS[name][0]
        channel, check, foreign = ros2_channel(topic, type_name), contract.SealCheck(self._key, topic, name), []
        clock = self.get_clock()

        def forward(data: bytes) -> None:
            if check.loops(data):
                self.counts[topic] = self.counts.get(topic, 0) + 1
                channel.log(data, log_time=clock.now().nanoseconds)
                return
            if not foreign:
                foreign.append(ros2_channel(FOREIGN_PREFIX + topic, type_name))
                self.get_logger().error(f"a message on {topic} is not sealed by this run's nodes: streamed apart on "
                                        f"{FOREIGN_PREFIX + topic}")
            self.foreign[topic] = self.foreign.get(topic, 0) + 1
            foreign[0].log(data, log_time=clock.now().nanoseconds)

        return forward

    def close(self) -> None:
        self._server.stop()
        print(COUNTS_PREFIX + json.dumps({"url": self.url, "counts": self.counts, "foreign": self.foreign}),
              flush=True)


def main(args=None) -> int:
    """``ros2 run nni_msgs_adapter foxglove_bridge``."""
    return run_node(FoxgloveBridge, args, prog="foxglove_bridge")


if __name__ == "__main__":
    sys.exit(main())
