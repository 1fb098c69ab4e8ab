"""The project's Rerun recording stream and where it goes: a file, a server, a viewer (pure core: rerun only).

All runs logged through :func:`open_recording` (the live bridge, ``nni-replay``)
share one application id and one recording id (``APP_ID``, ``RECORDING_ID``),
so that the viewer pools them into one recording: files of different runs
opened together (or merged with ``rerun rrd merge``) overlay in the same views.
"""

from __future__ import annotations

import os
import shutil
import sys
import urllib.parse
from pathlib import Path

import rerun as rr
import rerun.blueprint as rrb

from nni_msgs_adapter.viewing.rerun_layout import blueprint

#: Rerun application id of every stream this project writes.
APP_ID = "nni_battery_control"
#: Recording id of every stream this project writes: the viewer pools equal ids into one recording.
RECORDING_ID = "nni_battery_control_runs"


def _put_venv_rerun_on_path() -> None:
    """rr.spawn runs ``rerun`` from PATH; a venv entry point started by its full path has its bin dir off PATH."""
    if shutil.which("rerun") is None:
        os.environ["PATH"] = os.pathsep.join((str(Path(sys.executable).parent), os.environ.get("PATH", "")))


def recording_stream(app_id: str = APP_ID) -> rr.RecordingStream:
    """A recording stream with the project's shared recording id (runs in different files overlay)."""
    return rr.RecordingStream(app_id, recording_id=RECORDING_ID)


def open_recording(
    app_id: str,
    sink: tuple[str, str | int | None],
    *,
    layout: rrb.Blueprint | None = None,
) -> tuple[rr.RecordingStream, str | None]:
    """
    Create an explicit recording stream, attach a sink and send the blueprint.

    Parameters
    ----------
    app_id : str
        Rerun application id.
    sink : tuple
        ``("save", path)`` writes an ``.rrd`` file; ``("serve", port)`` hosts a
        gRPC server (``port``, or 9876 if ``None``) and the web viewer on
        port 9090, both on all network interfaces, for as long as the process
        runs; ``("connect", url)`` streams to a running viewer or server;
        ``("spawn", None)`` starts a native viewer.
    layout : rerun.blueprint.Blueprint or None
        Blueprint to send; defaults to :func:`blueprint`.

    Returns
    -------
    recording : rerun.RecordingStream
        The stream; independent of Rerun's global recording.
    url : str or None
        For ``"serve"``, the web-viewer URL that opens the live stream;
        otherwise ``None``.

    Raises
    ------
    ValueError
        If the sink kind is unknown.
    """
    kind, target = sink
    recording = recording_stream(app_id)
    url = None
    if kind == "save":
        recording.save(target)
    elif kind == "serve":
        grpc_url = recording.serve_grpc(grpc_port=target)
        rr.serve_web_viewer(open_browser=False)
        url = f"http://localhost:9090/?url={urllib.parse.quote(grpc_url, safe='')}"
    elif kind == "connect":
        recording.connect_grpc(target)
    elif kind == "spawn":
        _put_venv_rerun_on_path()
        recording.spawn()
    else:
        raise ValueError(f"unknown Rerun sink {kind!r}: expected 'save', 'serve', 'connect' or 'spawn'")
    recording.send_blueprint(blueprint() if layout is None else layout)
    return recording, url
