"""The demos' live view in Rerun (``nni-demo --rerun``, ``nni-demo --case ... --rerun``).

The ``--rerun`` option and the sink it names (save to a file, serve a web
viewer, spawn the native one), the start of the Rerun bridge node (and for
``serve`` of the web viewer it streams to), and serving until Ctrl-C. Each
demo waits for the bridge to have logged its runs itself (what it logs
differs). The bridge and the viewer are processes of the project's
supervisor, as every process of a demo.
"""

from __future__ import annotations

import argparse
import socket
import sys
import time
import urllib.parse
from pathlib import Path

from nni_msgs_adapter.ros.cli_support import CliError, writable_output
from nni_msgs_adapter.ros.processes import ChildError, Supervisor
from nni_msgs_adapter.viewing.bridge_protocol import READY_TEXT, URL_TEXT, display_missing

#: Seconds the Rerun bridge gets, once the run's recording is read, to report every one of its samples.
BRIDGE_WAIT_S = 30.0
#: Where the Rerun web viewer of ``--rerun serve`` listens (gRPC proxy, web page).
SERVE_GRPC_PORT, SERVE_WEB_PORT = 9876, 9090


def add_rerun_option(parser) -> None:
    """``--rerun`` of the SMIB and the network demo."""
    parser.add_argument("--rerun", nargs="+", metavar=("SINK", "PATH"), default=None,
                        help="stream the runs live to Rerun: 'save PATH' (.rrd), 'serve' (web viewer on this "
                             "machine, kept up until Ctrl-C) or 'spawn' (native viewer, needs a display); default: none")


def rerun_sink(words) -> dict:
    """What ``--rerun`` asks for: save PATH | serve [ADDRESS] | spawn (ADDRESS: where the viewer listens)."""
    sink, rest = words[0], words[1:]
    if sink not in ("save", "serve", "spawn") or len(rest) != {"save": 1, "serve": len(rest[:1]), "spawn": 0}[sink]:
        raise CliError("--rerun takes 'save PATH', 'serve [ADDRESS]' (default 127.0.0.1) or 'spawn'")
    if sink == "save":
        try:
            path = writable_output(rest[0])
        except argparse.ArgumentTypeError as exc:
            raise CliError(f"--rerun save: {exc}") from None
        return {"sink": "save", "path": str(path)}
    if sink == "spawn" and display_missing():
        raise CliError("--rerun spawn needs a display (DISPLAY and WAYLAND_DISPLAY are unset): "
                       "use --rerun save PATH or --rerun serve")
    if sink == "serve":
        return {"sink": "serve", "address": rest[0] if rest else "127.0.0.1"}
    return {"sink": sink}


def start_viewer(viewer: Supervisor, sink: dict, f0_hz: float, **network):
    """Start the Rerun bridge (and for ``serve`` the web viewer it streams to); return the bridge.

    ``network``: the bridge's ``namespaces``, ``case`` and ``coi_weights`` for a network's generators.
    """
    params = {**sink, "f0_hz": f0_hz, **network}
    if sink["sink"] == "serve":
        # The SDK's own server listens on every interface; the rerun CLI's binds where it is told.
        host = sink["address"]
        viewer.start("rerun_viewer", [str(Path(sys.executable).parent / "rerun"), "--serve-web", "--bind", host,
                                      "--port", str(SERVE_GRPC_PORT), "--web-viewer-port", str(SERVE_WEB_PORT)])
        proxy = f"rerun+http://{host}:{SERVE_GRPC_PORT}/proxy"
        params = {"sink": "connect", "url": proxy, "f0_hz": f0_hz, **network}
        wait_for_port(viewer["rerun_viewer"], host, SERVE_GRPC_PORT)
        print(f"{URL_TEXT} http://{host}:{SERVE_WEB_PORT}/?url={urllib.parse.quote(proxy, safe='')}",
              flush=True)
    bridge = viewer.start_node("rerun_bridge", "nni_msgs_adapter.viewing.rerun_bridge", params)
    try:
        bridge.wait_for_line(READY_TEXT, timeout_s=30.0)
    except ChildError as error:
        raise CliError(f"the Rerun bridge did not start: {error}") from None
    return bridge


def wait_for_port(child, host: str, port: int, timeout_s: float = 30.0) -> None:
    """Wait until ``child`` accepts TCP connections on host:port; CliError if it exits or times out."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            socket.create_connection((host, port), timeout=0.5).close()
            return
        except OSError:
            if child.poll() is not None or time.monotonic() > deadline:
                raise CliError(f"the Rerun web viewer did not listen on {host}:{port}: {child.tail()}") from None
            time.sleep(0.1)


def wait_for_interrupt(message: str) -> None:
    """Print ``message``, then block until Ctrl-C (SIGINT) or SIGTERM (a signal right after the message is caught too)."""
    try:
        print(message, flush=True)
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
