"""The demos' live view in Foxglove (``nni-demo --foxglove [HOST:]PORT``, networks too; issue 34).

Each run gets a Foxglove bridge node (:mod:`nni_msgs_adapter.viewing.foxglove_bridge`), serving before the
run's logger starts (a port in use stops the run before any file is written), with
the run's key (so that a rogue's messages are streamed apart, as the logger records them apart) and a label of
the run (b, law, case or scenario, mode) on ``/nni/run``. The plant's run is released only once the bridge has
subscribed to every ``pmu`` and controller topic, and the plant counts it among the readers it waits for: a
client connected from the start sees every sample. The server is the same address run after run (a client
reconnects when a run ends: Foxglove does so by itself). A lockstep run is over in a fraction of a second, before
a client that reconnects can subscribe: with ``--foxglove-wait`` each run starts only once a client has subscribed
to one of its loop channels (the bridge logs each subscription), and waits for it as long as it takes. Once the run
is judged, its verdict goes to the bridge (a file it watches) and out on ``/nni/verdict`` before the bridge stops.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from nni_msgs_adapter.c37118.profile import address_text, parse_server_address
from nni_msgs_adapter.ros.cli_support import CliError
from nni_msgs_adapter.ros.processes import ChildError
from nni_msgs_adapter.viewing.foxglove_bridge import SERVING_TEXT, SUBSCRIBED_PREFIX, VERDICT_PREFIX
from nni_battery_controller.demo_common import wait_for_recorder

#: Where ``--foxglove`` without an address serves: Foxglove's default port, on loopback.
DEFAULT_ADDRESS = "127.0.0.1:8765"
MODULE = "nni_msgs_adapter.viewing.foxglove_bridge"
#: How long a bridge may take to listen (a loaded machine starts a Python process slowly).
SERVE_WAIT_S = 60.0
#: How long a bridge may take to send a run's verdict once it is written (it looks every discovery period, 0.1 s).
VERDICT_WAIT_S = 30.0
#: The file in a run's log folder the demo writes its verdict to, for the bridge.
VERDICT_FILE = "foxglove_verdict.json"


def add_foxglove_option(parser) -> None:
    """``--foxglove [[HOST:]PORT]`` of the SMIB and the network demo."""
    parser.add_argument("--foxglove", nargs="?", const=DEFAULT_ADDRESS, default=None, metavar="[HOST:]PORT",
                        help="stream every run live to Foxglove over its WebSocket protocol at [HOST:]PORT "
                             f"(alone: {DEFAULT_ADDRESS}; loopback unless a host is named); default: off")
    parser.add_argument("--foxglove-wait", action="store_true",
                        help="with --foxglove: start each run only once a Foxglove client has subscribed to it (a "
                             "lockstep run is otherwise over before a reconnecting client can subscribe; default: off)")


def foxglove_address(args) -> str | None:
    """The checked ``--foxglove`` address (``host:port``), None without the option; CliError (one line) if bad."""
    if args.foxglove is None:
        if args.foxglove_wait:
            raise CliError("--foxglove-wait applies only with --foxglove")
        return None
    try:
        host, port = parse_server_address(args.foxglove, what="--foxglove: a Foxglove server address")
    except ValueError as exc:
        raise CliError(str(exc)) from None
    if port == 0:
        raise CliError("--foxglove needs a port a client can be told (not 0)")
    return address_text(host, port)


def start_bridge(procs, address: str | None, env: dict, label: dict, logs: Path):
    """Start the run's Foxglove bridge at ``address`` (None: none, and None returned) and wait until it serves,
    before anything of the run writes a file: a port in use stops the run with the bridge's one line."""
    if address is None:
        return None
    bridge = procs.start_node("foxglove_bridge", MODULE, {"address": address, "discovery_period_s": 0.1,
                                                          "run_label": json.dumps(label),
                                                          "verdict_file": str(logs / VERDICT_FILE)}, env=env)
    try:
        bridge.wait_for_line(SERVING_TEXT, SERVE_WAIT_S)
    except ChildError:
        raise CliError(f"the Foxglove bridge is not serving: {bridge.last_line()} (logs in {logs})") from None
    return bridge


def wait_streaming(bridge, writers: dict, logs: Path, index: int, hold: bool) -> None:
    """Wait until ``bridge`` (None: nothing to wait for) has matched the loop's ``writers`` (as the logger), print
    its URL at the first run (``index`` 1), and with ``hold`` (``--foxglove-wait``) wait until a client has
    subscribed to one of the loop's channels (:func:`subscribed_to_loop`): every channel is offered by then, so a
    client that subscribes to all it wants at once (Foxglove does) sees the run from its first sample."""
    if bridge is None:
        return
    wait_for_recorder(bridge, writers, logs, "the Foxglove bridge")
    url = next(line.split(SERVING_TEXT, 1)[1].strip() for line in bridge.output().splitlines() if SERVING_TEXT in line)
    if index == 1:
        print(f"  Foxglove: {url} (Open connection > Foxglove WebSocket; layout: docs/foxglove/)", flush=True)
    if not hold:
        return
    print(f"  run {index} waits for a Foxglove client at {url} to subscribe", flush=True)
    while not subscribed_to_loop(bridge.output(), writers):
        if bridge.poll() is not None:
            raise CliError(f"the Foxglove bridge exited while run {index} waited for a client: {bridge.last_line()} "
                           f"(logs in {logs})")
        time.sleep(0.05)


def subscribed_to_loop(output: str, writers: dict) -> bool:
    """Whether the bridge's ``output`` logs a client's subscription to one of the loop's ``writers``' topics. The
    bridge's own channels do not count: a client that connects before the loop's channels exist subscribes to
    /nni/run at once and to the rest only as they are offered (CI once saw a lockstep run released by that first
    subscription end before the client had subscribed to /gen1/battery/command)."""
    return any(line.split(SUBSCRIBED_PREFIX, 1)[1].strip() in writers
               for line in output.splitlines() if SUBSCRIBED_PREFIX in line)


def stream_verdict(bridge, logs: Path, verdict: dict) -> None:
    """Give ``bridge`` (None: nothing to do) the run's ``verdict`` (``verdict``: the words the demo prints; the
    rest as the summary says) and wait until it has sent it on /nni/verdict: the stream ends with it."""
    if bridge is None:
        return
    path = logs / VERDICT_FILE
    partial = path.with_suffix(".partial")
    partial.write_text(json.dumps(verdict), encoding="utf-8")  # b = inf: the bridge sends the word, as for the label
    os.replace(partial, path)  # whole or not at all: the bridge never reads half a verdict
    try:
        bridge.wait_for_line(VERDICT_PREFIX, VERDICT_WAIT_S)
    except ChildError:
        raise CliError(f"the Foxglove stream is partial: the bridge did not send the run's verdict "
                       f"({bridge.last_line()}; logs in {logs})") from None


def stated(bridge) -> list:
    """The bridge's read-back entry (it has to have read the run's key before it is removed)."""
    return [] if bridge is None else [(bridge, {"/foxglove_bridge": {}})]


def launch_bridge(enabled: str, address: str, label: dict) -> dict | None:
    """The Foxglove bridge's parameters for the launch arguments ``foxglove`` (true/false) and
    ``foxglove_address`` (None when off); ValueError (one line) for a word that is neither or a bad address."""
    word = str(enabled).strip().lower()
    if word not in ("true", "false"):
        raise ValueError(f"foxglove takes true or false, got {enabled!r}")
    if word == "false":
        return None
    host, port = parse_server_address(str(address), what="foxglove_address: a Foxglove server address")
    return {"address": address_text(host, port), "run_label": json.dumps(label)}
