"""``nni-demo --measurements c37118``: the demos' controllers fed through the plant's IEEE C37.118.2 stream.

The plant serves its stream on a free loopback port (``pmu_port`` 0; the port
read back from its "listening on" line, :class:`.demo_pmu.StreamWatch`), or
where ``--pmu-server`` puts it, FREQ/DFREQ as floats, and starts its run only
once the client (and the PDCs ``--pmu-wait-for-pdcs`` asks for) turned data on. The ``c37118_client`` node
(:mod:`nni_msgs_adapter.c37118.client_node`, station k in the k-th
generator's namespace) connects once every station's ``c37118/pmu`` has its
readers (the controllers and the logger) and publishes each station there;
the controllers read ``c37118/pmu`` instead of ``pmu``
(``measurement_topic``). The plant's own ``pmu`` is still published and
recorded: the recording holds both. Both demos (SMIB and ``--case``) use
these helpers alike.
"""

from __future__ import annotations

from nni_msgs_adapter.c37118 import profile
from nni_msgs_adapter.ros.cli_support import CliError
from nni_msgs_adapter.ros.defaults import controller_defaults
from nni_msgs_adapter.ros.processes import ChildError

#: ``--measurements``: the plant's ROS topic, or its C37.118 stream through the client node.
MEASUREMENTS = ("ros", "c37118")
CLIENT_MODULE = "nni_msgs_adapter.c37118.client_node"
#: The controllers' measurement topic (``measurement_topic``) fed through the stream.
STREAM_TOPIC = "c37118/pmu"
#: Where a launch file serves the client's stream when its ``pmu_port`` gives none (C37.118's customary port).
LAUNCH_PORT = 4712
#: Seconds the client gets to connect once started.
CONNECT_WAIT_S = 60.0
_CONNECTED = "connected to PMU"


def add_measurements_option(parser) -> None:
    parser.add_argument("--measurements", choices=MEASUREMENTS, default="ros",
                        help="how the controllers get the measurements: ros, the plant's pmu topic (default), or "
                             "c37118, the plant's IEEE C37.118.2 stream on a loopback port read by the c37118_client "
                             "node (rates 10, 25, 50, 100 frames/s at 50 Hz; 10 ... 120 at 60 Hz)")


def plant_parameters(measurements: str, port: int = 0, host: str = "127.0.0.1", other_pdcs: int = 0) -> dict:
    """The plant's stream parameters for the client at ``host:port`` (0: a free port): FREQ as floats, the run
    waiting for the client and ``other_pdcs`` more; none for measurements ``ros``."""
    if measurements != "c37118":
        return {}
    return {"pmu_port": port, "pmu_host": host, "pmu_freq_format": "float", "pmu_wait_for_pdcs": other_pdcs + 1}


def launch_stream(measurements: str, pmu_port: int, pmu_host: str) -> tuple[int, dict]:
    """A launch file's stream: ``(its port, the plant's stream parameters for the client)``, served on
    ``pmu_port`` or, when that gives none (-1), on :data:`LAUNCH_PORT`; ``(pmu_port, {})`` for measurements
    ``ros``. ValueError for another ``measurements``, or for port 0 (a port the launch cannot learn)."""
    if measurements not in MEASUREMENTS:
        raise ValueError(f"measurements must be one of {', '.join(MEASUREMENTS)}, got {measurements!r}")
    if measurements != "c37118":
        return pmu_port, {}
    if pmu_port == 0:
        raise ValueError("measurements:=c37118 needs a fixed pmu_port (the client connects to it), got 0")
    port = LAUNCH_PORT if pmu_port < 0 else pmu_port
    return port, plant_parameters(measurements, port, pmu_host)


def controller_parameters(measurements: str) -> dict:
    """The controllers' measurement topic (the default, ``pmu``, for measurements ``ros``)."""
    return {"measurement_topic": STREAM_TOPIC} if measurements == "c37118" else {}


def plant_readers(measurements: str, readers: int, bridge: bool = False) -> int:
    """The readers the plant waits for on each ``pmu``: ``readers`` (the logger and the controllers) and a Rerun
    bridge; through the stream the controllers read ``c37118/pmu`` instead, and the client waits for them there."""
    return (1 if measurements == "c37118" else readers) + bridge


def client_host(server_host: str) -> str:
    """Where the client connects to a stream that listens on ``server_host``: every interface read on loopback."""
    return "127.0.0.1" if server_host in ("0.0.0.0", "::") else server_host


def client_parameters(port: int, mode: str, readers: int, namespaces=(), host: str = "127.0.0.1",
                      idcode: int = 1) -> dict:
    """The client node's parameters: the stream ``idcode`` at ``host:port``, the plant's ``mode`` (a launch passes
    its substitutions), station k in the k-th of ``namespaces`` (none: one station, the node's own namespace),
    connecting once each has ``readers``."""
    params = {"pmu_host": host, "pmu_port": port, "pmu_idcode": idcode, "mode": mode, "wait_for_subscribers": readers,
              "max_age_s": controller_defaults()["stamp_tolerance_s"]}
    return {**params, "namespaces": list(namespaces)} if namespaces else params


def start_client(procs, where: str, measurements: str, mode: str, readers: int, namespaces=(), idcode: int = 1,
                 env=None):
    """The client node, on the stream at ``where`` (``host:port`` as the plant says it listens; every interface
    read on loopback), in the plant's ``mode``; it connects once each station's topic has ``readers``
    subscribers (``env``: its environment's additions, the run's key). None for measurements ``ros``."""
    if measurements != "c37118":
        return None
    host, port = profile.parse_server_address(where)
    return procs.start_node("c37118_client", CLIENT_MODULE,
                            client_parameters(port, mode, readers, namespaces, client_host(host), idcode), env=env)


def wait_connected(client, label: str) -> None:
    """Wait for the client's connection to the stream and say so (one progress line)."""
    if client is None:
        return
    try:
        line = client.wait_for_line(_CONNECTED, CONNECT_WAIT_S)
    except ChildError as error:
        raise CliError(f"the C37.118 client did not connect: {error}") from None
    print(f"  {label} C37.118: {line}, the controllers read {STREAM_TOPIC}")
