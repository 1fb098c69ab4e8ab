"""``main()`` plumbing shared by the nodes: start, spin, clean shutdown, one-line errors.

SIGINT and SIGTERM only ask the spin loop to stop; the node's ``close()`` then
runs with the ROS context still valid (final diagnostics go out, files are
finished), the last reliable messages get up to ``ACK_TIMEOUT_S`` to be
acknowledged (a process that exits right after publishing would otherwise take
its unsent samples with it; reliable writers heartbeat every 50 ms, see
``config/fastdds_profiles.xml``, so this takes milliseconds), and the process
exits 0. rclpy's own handlers are not installed: they
would invalidate the context before ``close()`` could publish. Invalid start-up
parameters print one line naming the problem and exit 2. Once made, each node
that states its parameters (``effective_parameters``) has them printed as one
line on stdout (:mod:`.readback`), before it spins.

Before ROS starts:

- ``--help`` prints the node's usage and parameters (its module's ``parameters()``
  table) and exits 0, starting nothing; any other argument outside
  ``--ros-args`` is refused with one line, exit 2.
- The DDS network (issue 11, attack 7): every participant binds to loopback
  only (``config/fastdds_profiles.xml``) unless ``NNI_NETWORK=multihost``
  selects ``config/fastdds_profiles_multihost.xml`` (reachable from the network,
  for a loop spread over hosts: other hosts named in ``ROS_STATIC_PEERS``). A
  ``FASTRTPS_DEFAULT_PROFILES_FILE`` of the user's own is used as it is (said on
  the node's log); set together with ``NNI_NETWORK`` it is refused.
- Many participants on one host: rmw_fastrtps (Jazzy) under
  ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` announces a participant to the
  discovery ports of the host's first 32 participants of the domain only (the
  ``maxInitialPeersRange`` of its UDP transport), so two participants beyond
  the 32nd never discover each other. A deployment that starts more processes
  says how many in ``NNI_DDS_PARTICIPANTS`` (``processes.PARTICIPANTS_ENV``;
  nni-demo, the bench and the network launch file set it): above 32 the
  node gets the loopback profile with its UDP transport's
  ``maxInitialPeersRange`` raised to cover them (a copy written to a folder
  of the user's own in the temporary directory; the whitelist and everything
  else as shipped). Not
  always raised: each step of 32 costs every participant as many more
  announcement datagrams a second (measured: 13 idle participants used 1.7 %
  of a core more with 128 than with 32).
- SROS2: with ``ROS_SECURITY_ENABLE=true`` the strategy defaults to ``Enforce``
  (ROS's default, ``Permissive``, silently runs without security when the
  enclave is missing), and a middleware that cannot do DDS Security (the Fast
  DDS of the PyPI wheels has no security plugins) or an unusable keystore stops
  the node with one line and exit 2 instead of a traceback.
"""

from __future__ import annotations

import os
import signal
import sys
import textwrap
import time
import warnings
from pathlib import Path

import rclpy
from rclpy.duration import Duration
from rclpy.exceptions import ParameterException
from rclpy.executors import SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from rclpy.utilities import remove_ros_args

from nni_msgs_adapter.ros.cli_support import EXIT_USAGE
from nni_msgs_adapter.ros.defaults import config_path
from nni_msgs_adapter.ros.processes import PARTICIPANTS_ENV
from nni_msgs_adapter.ros.readback import parameters_line

#: Longest wait inside the executor, s: how soon a signal is noticed.
_SIGNAL_POLL_S = 0.05
#: Fast DDS (2.x, Jazzy) takes its default QoS profiles from the XML file this names.
FASTDDS_PROFILES_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"
#: Selects the DDS network of the nodes: a key of NETWORK_PROFILES (default DEFAULT_NETWORK).
NETWORK_ENV = "NNI_NETWORK"
#: NNI_NETWORK value -> Fast DDS profile in nni_msgs_adapter/config.
NETWORK_PROFILES = {"loopback": "fastdds_profiles.xml", "multihost": "fastdds_profiles_multihost.xml"}
DEFAULT_NETWORK = "loopback"
#: Participants of a domain that rmw_fastrtps (Jazzy) discovers on one host under LOCALHOST discovery (the
#: maxInitialPeersRange it gives its UDP transport); a wider range is given in steps of this.
LOCALHOST_PEER_RANGE = 32
#: Most participants of one domain on one host: RTPS gives participant i the ports 7410 + 250 d + 2 i, so
#: beyond 120 they run into the next domain's (d + 1) ports.
MAX_PARTICIPANTS = 120
#: File name prefix of the loopback profile copies with a wider range (in the temporary directory).
_WIDENED_PREFIX = "nni_fastdds_loopback_peers"
#: The Fast DDS profile schema's namespace.
_FASTDDS_XMLNS = "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"
#: SROS2 switches read by rcl.
SECURITY_ENABLE_ENV = "ROS_SECURITY_ENABLE"
SECURITY_STRATEGY_ENV = "ROS_SECURITY_STRATEGY"
#: Longest wait at exit for reliable subscribers to acknowledge what was published, s.
ACK_TIMEOUT_S = 2.0
#: rmw_fastrtps's error when Fast DDS was built without the DDS Security plugins.
_NO_SECURITY_LIBRARIES = "doesn't have the security libraries"
#: Width of the --help text.
_HELP_WIDTH = 88


class StartupError(Exception):
    """A configuration that stops a node before ROS starts: one line, exit ``EXIT_USAGE``."""


def run_node(factory, args=None, prog: str = "node") -> int:
    """Construct ``factory()`` and spin it until a signal or until it reports done.

    ``factory()`` returns a node or a list of nodes (a composed deployment: all
    spin on the one executor, and all are closed and destroyed on the way out).
    A node may offer ``done`` (an rclpy Future completed when its run is over,
    e.g. the plant after its duration; any node's ends the process) and
    ``close()`` (called before it is destroyed, still able to publish). ``args``
    are the process arguments, program name first, as for ``rclpy.init``
    (None: ``sys.argv``).
    """
    try:
        user_args = remove_ros_args(sys.argv if args is None else list(args))[1:]
    except _rclpy.UnknownROSArgsError as exc:
        print(f"{prog}: error: unknown arguments after --ros-args: {exc} (see --help)", file=sys.stderr)
        return EXIT_USAGE
    except _rclpy.RCLInvalidROSArgsError as exc:
        print(f"{prog}: error: {_rcl_reason(str(exc))} (see --help)", file=sys.stderr)
        return EXIT_USAGE
    if any(arg in ("-h", "--help") for arg in user_args):
        print(help_text(factory, prog))
        return 0
    try:
        if user_args:
            raise StartupError(f"unrecognized arguments: {' '.join(user_args)} "
                               "(node parameters go after --ros-args: -p name:=value; see --help)")
        own_profile = select_dds_profile(os.environ)
        if security_requested(os.environ):
            os.environ.setdefault(SECURITY_STRATEGY_ENV, "Enforce")
    except StartupError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except _rclpy.RCLError as exc:
        return _security_failure(exc, prog)
    try:
        # rclpy warns about the half-made node it cleans up after an rcl error;
        # held back here so that a failed secure start says one thing only.
        with warnings.catch_warnings(record=True) as held:
            warnings.simplefilter("always")
            node = factory()
    except (ValueError, ParameterException) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return EXIT_USAGE
    except _rclpy.RCLError as exc:
        rclpy.try_shutdown()
        return _security_failure(exc, prog)
    for warning in held:
        warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)
    nodes = list(node) if isinstance(node, (list, tuple)) else [node]
    for each in nodes:  # the read-back: what each node runs with, before anything spins (readback.py)
        if hasattr(each, "effective_parameters"):
            print(parameters_line(prog, each.get_fully_qualified_name(), each.effective_parameters()), flush=True)
    if own_profile is not None:
        nodes[0].get_logger().info(f"DDS profile from {FASTDDS_PROFILES_ENV}={own_profile}: the network the node "
                                   "listens on is as that file says (the loopback-only default is not applied)")
    stop = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda number, frame: stop.append(number))
    executor = make_executor(any(getattr(each, "needs_message_info", False) for each in nodes))
    for each in nodes:
        executor.add_node(each)
    dones = [each.done for each in nodes if getattr(each, "done", None) is not None]
    # The executor dispatches in C++ for up to _SIGNAL_POLL_S at a time and stops at once when a node's run is
    # over (``finished``, a future of each slice, completed by any ``done``). One spin_once per event, as
    # before, cost the receiver 51 us of CPU a message against 40 (a raw subscription at 5000 messages/s,
    # alternating runs): the plant and the composed controllers take N messages a lockstep sample.
    finished = [Future()]
    for done in dones:
        done.add_done_callback(lambda _: finished[0].done() or finished[0].set_result(True))
    try:
        while not stop and not any(done.done() for done in dones):
            finished[0] = Future()
            executor.spin_until_future_complete(finished[0], timeout_sec=_SIGNAL_POLL_S)
    finally:
        for each in nodes:
            close = getattr(each, "close", None)
            if close is not None:
                close()
        for each in nodes:
            wait_for_acks(each)
        executor.shutdown(timeout_sec=1.0)
        for each in nodes:
            each.destroy_node()
        rclpy.try_shutdown()
    return 0


def network_profile(network: str) -> Path:
    """The Fast DDS profile file of an ``NNI_NETWORK`` value."""
    return config_path("nni_msgs_adapter", NETWORK_PROFILES[network])


def select_dds_profile(environ) -> str | None:
    """Point ``FASTRTPS_DEFAULT_PROFILES_FILE`` in ``environ`` at the profile ``NNI_NETWORK`` selects.

    With ``NNI_DDS_PARTICIPANTS`` above ``LOCALHOST_PEER_RANGE``, the loopback
    profile with a discovery range covering them (:func:`loopback_profile_for`).
    Fast DDS reads the variable when the first participant is created, after
    this. Returns the user's own profile file when one is set and left alone
    (None when the file is ours); raises StartupError for an unknown
    ``NNI_NETWORK``, one set beside a profile file of the user's own, or a
    participant count that is not a count, is beyond ``MAX_PARTICIPANTS``, or
    above 32 where it cannot be honoured (the multi-host profile, a profile of
    the user's own).
    """
    network = environ.get(NETWORK_ENV, "")
    if network and network not in NETWORK_PROFILES:
        raise StartupError(f"{NETWORK_ENV} must be one of {', '.join(NETWORK_PROFILES)}, got {network!r}")
    participants = participant_count(environ)
    many = participants > LOCALHOST_PEER_RANGE
    own = environ.get(FASTDDS_PROFILES_ENV, "")
    names = [network] if network else list(NETWORK_PROFILES)
    ours = {network_profile(name).resolve(): name for name in names}
    if own and Path(own).resolve() not in ours and not is_widened_loopback(own):
        if network:
            raise StartupError(f"{NETWORK_ENV}={network} and {FASTDDS_PROFILES_ENV}={own} both choose the DDS "
                               "profile: unset one of them")
        if many:
            raise StartupError(f"{PARTICIPANTS_ENV}={participants} needs the loopback profile with a wider discovery "
                               f"range, but {FASTDDS_PROFILES_ENV}={own} is set: unset it, or raise "
                               "maxInitialPeersRange in that file and unset the count")
        return own
    chosen = network or (ours.get(Path(own).resolve(), DEFAULT_NETWORK) if own else DEFAULT_NETWORK)
    if many:
        if chosen != DEFAULT_NETWORK:
            raise StartupError(f"{PARTICIPANTS_ENV}={participants}: more than {LOCALHOST_PEER_RANGE} participants "
                               f"on a host are discovered with the {DEFAULT_NETWORK} profile only, not {chosen}")
        environ[FASTDDS_PROFILES_ENV] = str(loopback_profile_for(participants))
    elif not own:
        environ[FASTDDS_PROFILES_ENV] = str(network_profile(chosen))
    return None


def participant_count(environ) -> int:
    """``NNI_DDS_PARTICIPANTS`` (0 when unset): the deployment's processes on this host; StartupError if invalid."""
    text = environ.get(PARTICIPANTS_ENV, "")
    try:
        count = int(text) if text else 0
    except ValueError:
        count = -1
    if not 0 <= count <= MAX_PARTICIPANTS:
        raise StartupError(f"{PARTICIPANTS_ENV} must be a count of processes, 0 to {MAX_PARTICIPANTS} (the RTPS "
                           f"ports of one domain on one host), got {text!r}")
    return count


def peer_range(participants: int) -> int:
    """The ``maxInitialPeersRange`` that covers ``participants``: whole steps of 32, at most ``MAX_PARTICIPANTS``."""
    return min(-(-participants // LOCALHOST_PEER_RANGE) * LOCALHOST_PEER_RANGE, MAX_PARTICIPANTS)


def _widened_folder() -> Path:
    """This user's folder of widened loopback profiles (``$TMPDIR/nni-dds-<uid>``)."""
    import tempfile

    return Path(tempfile.gettempdir()) / f"nni-dds-{os.getuid()}"


def is_widened_loopback(path: str) -> bool:
    """Whether ``path`` is a copy of the loopback profile written by :func:`loopback_profile_for` (in its folder)."""
    resolved = Path(path).resolve()
    return resolved.parent == _widened_folder().resolve() and resolved.name.startswith(_WIDENED_PREFIX)


def loopback_profile_for(participants: int) -> Path:
    """The shipped loopback profile with its UDP transport's ``maxInitialPeersRange`` covering ``participants``.

    Written once to a directory of this user's own in the temporary directory
    (mode 0700: no other local user can plant a profile there that opens the
    loop to the network), named by the range and the shipped file's digest
    (every process of a deployment finds the same file; a changed profile gets
    a new one), atomically (processes starting together never read a
    half-written file).
    """
    import hashlib
    import xml.etree.ElementTree as ElementTree

    shipped = network_profile(DEFAULT_NETWORK)
    peers = peer_range(participants)
    digest = hashlib.sha256(shipped.read_bytes()).hexdigest()[:12]
    folder = _widened_folder()
    folder.mkdir(mode=0o700, exist_ok=True)
    status = folder.stat()
    if status.st_uid != os.getuid() or status.st_mode & 0o077:
        raise StartupError(f"{folder} is not a folder of this user's alone (owner {status.st_uid}, mode "
                           f"{status.st_mode & 0o777:o}): it would hold the DDS profile of the nodes; remove it")
    path = folder / f"{_WIDENED_PREFIX}{peers}_{digest}.xml"
    if path.exists():
        return path
    ElementTree.register_namespace("", _FASTDDS_XMLNS)
    tree = ElementTree.parse(shipped)
    udp = [d for d in tree.iter(f"{{{_FASTDDS_XMLNS}}}transport_descriptor")
           if d.findtext(f"{{{_FASTDDS_XMLNS}}}type") == "UDPv4"]
    if len(udp) != 1:
        raise StartupError(f"the shipped DDS profile {shipped} has {len(udp)} UDPv4 transports, expected one")
    element = ElementTree.Element(f"{{{_FASTDDS_XMLNS}}}maxInitialPeersRange")
    element.text = str(peers)
    udp[0].insert(list(udp[0]).index(udp[0].find(f"{{{_FASTDDS_XMLNS}}}type")) + 1, element)
    tree.getroot().insert(0, ElementTree.Comment(
        f" {shipped.name} with maxInitialPeersRange {peers} on its UDP transport, for {PARTICIPANTS_ENV} up to "
        f"{peers} (nni_msgs_adapter.ros.node_main); see that file for the rest. "))
    part = path.with_name(f"{path.name}.{os.getpid()}.part")
    tree.write(part, xml_declaration=True, encoding="UTF-8")
    os.replace(part, path)
    return path


def security_requested(environ) -> bool:
    """Whether SROS2 is switched on (rcl enables security for exactly ``true``)."""
    return environ.get(SECURITY_ENABLE_ENV, "") == "true"


def _security_failure(exc, prog: str) -> int:
    """One line for an rcl error when security was requested (else the error propagates); exit 2."""
    if not security_requested(os.environ):
        raise exc
    print(f"{prog}: error: {security_error_text(str(exc))}", file=sys.stderr)
    return EXIT_USAGE


def security_error_text(rcl_error: str) -> str:
    """What a failed secure start means, in one line, from rcl's error text."""
    if _NO_SECURITY_LIBRARIES in rcl_error:
        return (f"DDS security requested ({SECURITY_ENABLE_ENV}=true) but not supported: this Fast DDS is built "
                "without the DDS Security plugins (as the PyPI wheels are); SROS2 needs a ROS 2 Jazzy install "
                "(README, Security)")
    return (f"DDS security requested ({SECURITY_ENABLE_ENV}=true, {SECURITY_STRATEGY_ENV}="
            f"{os.environ.get(SECURITY_STRATEGY_ENV)}) but the node cannot start securely: {_rcl_reason(rcl_error)}")


def _rcl_reason(rcl_error: str) -> str:
    """The first line of an rcl error without its source location (``, at /project/src/...``)."""
    return rcl_error.splitlines()[0].split(", at /")[0]


def help_text(factory, prog: str) -> str:
    """Usage of a node: its module's summary, its parameters with defaults, and the environment it reads.

    The parameters are the table (ros_params.Spec) that ``parameters()`` of the module
    that defines ``factory`` returns; the defaults shown are those the node starts with
    (read from its config file only now, not when the module was imported).
    """
    module = sys.modules.get(getattr(factory, "__module__", ""), None)
    summary = ((getattr(module, "__doc__", None) or "").strip().split("\n\n") or [""])[0]
    specs = module.parameters() if hasattr(module, "parameters") else ()
    lines = [f"usage: {prog} [-h] [--ros-args [-p NAME:=VALUE ...] [--params-file FILE] [-r __ns:=/NAMESPACE]]",
             "", *textwrap.wrap(" ".join(summary.split()), _HELP_WIDTH), ""]
    if specs:
        lines.append("parameters (-p NAME:=VALUE; default in brackets; read-only ones only at start):")
        for spec in specs:
            text = spec.description
            if spec.choices:
                text += f" One of: {', '.join(spec.choices)}."
            if spec.low is not None and spec.high is not None and not isinstance(spec.default, bool):
                text += f" Range {_number_text(spec.low, spec.default)} to {_number_text(spec.high, spec.default)}."
            if spec.read_only:
                text += " Read-only."
            lines += _help_entry(f"{spec.name} [{_default_text(spec.default)}]", text)
        lines.append("")
    lines.append("environment:")
    lines += _help_entry(f"{NETWORK_ENV} [{DEFAULT_NETWORK}]",
                         "loopback: DDS only on 127.0.0.1 and shared memory (other hosts and network namespaces "
                         "cannot join); multihost: every interface, for a loop over several hosts (name them in "
                         "ROS_STATIC_PEERS).")
    lines += _help_entry(f"{PARTICIPANTS_ENV} [unset]",
                         f"how many ROS processes the deployment runs on this host (nni-demo --case and the network "
                         f"launch file set it); above {LOCALHOST_PEER_RANGE}, the loopback profile's discovery range "
                         f"is widened to cover them (at most {MAX_PARTICIPANTS}).")
    lines += _help_entry(f"{SECURITY_ENABLE_ENV}, ROS_SECURITY_KEYSTORE, --ros-args --enclave /nni/<node>",
                         "SROS2 on ROS 2 Jazzy installs (the PyPI Fast DDS has no DDS Security): README, Security.")
    return "\n".join(lines)


def _help_entry(name: str, text: str) -> list[str]:
    """One name of the help and its wrapped, indented description."""
    return [f"  {name}", *textwrap.wrap(text, _HELP_WIDTH, initial_indent="      ", subsequent_indent="      ")]


def _number_text(value: float, default) -> str:
    """A range bound as the parameter's type prints it (integers whole)."""
    return str(int(value)) if isinstance(default, int) else f"{value:g}"


def _default_text(value) -> str:
    """A default as it is typed on the command line (``.inf``, ``true``, ``''``)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and value == float("inf"):
        return ".inf"
    return repr(value) if value == "" else str(value)


def make_executor(needs_message_info: bool = False):
    """The executor every node of the project spins: rclpy's EventsExecutor where available.

    A node whose subscription callbacks take the message info (``needs_message_info``, the
    MCAP logger) gets SingleThreadedExecutor: the EventsExecutor of rclpy 7.1 raises
    ``SystemError: null argument to internal routine`` on such a callback (measured).

    Measured at 100 frames/s (realtime loop, alternating runs on one machine):
    the loop's latency p50 fell by about a quarter against SingleThreadedExecutor
    (1.3-1.6 ms to 0.9-1.2 ms), because it dispatches a ready subscription from
    C++ instead of rebuilding the wait set over every timer, service and
    subscription in Python on each wake-up. It is in ``rclpy.experimental`` in
    Jazzy (7.1.x); an rclpy without it gets SingleThreadedExecutor.
    """
    if needs_message_info:
        return SingleThreadedExecutor()
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:
        return SingleThreadedExecutor()
    return EventsExecutor()


def wait_for_acks(node, timeout_s: float = ACK_TIMEOUT_S) -> None:
    """Block until every reliable subscriber has acknowledged every publisher's samples, or the timeout."""
    deadline = time.monotonic() + timeout_s
    for publisher in node.publishers:
        remaining = max(deadline - time.monotonic(), 0.0)
        publisher.wait_for_all_acked(Duration(nanoseconds=int(remaining * 1e9)))
