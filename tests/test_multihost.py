"""Across hosts (issue 14, item 4): the plant on one host, the controllers on another, over DDS.

Two network namespaces stand for the two hosts (tests/netns.py): each has
only ``lo`` and its end of a veth link between them (private 10.213.x.y/30
addresses, on the veth only), and its own ``/dev/shm``, so that nothing
crosses between them but IP over that link. Host A runs the plant; host B the
controller(s) and the MCAP logger that records the run. Every node is started
the way README's "Several hosts" section says:

    NNI_NETWORK=multihost ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_STATIC_PEERS=<the other host>

(the multi-host profile; discovery only to the named peer, no multicast).
The same loop is then run on one host (this namespace, the loopback-only
default) and the two recordings must be equal bit for bit: every message of
every topic but ``/diagnostics`` (its contents are wall-clock statistics),
the serialized CDR bytes, in order (the invariant set's header stamp aside:
the plant stamps it with the wall clock). A third namespace, a decoy, is linked to
both hosts and listens (tests/udp_sniffer.py): not one UDP datagram may reach
it, which it does (multicast discovery) under ROS's default range SUBNET (the
test's control, so that the silence is not vacuous).

Both runs have two busy processes beside them (discovery-dependent flows).
The controllers' stale watchdog (wall clock: ``stale_after_periods``) is set
to 1000 periods in both runs: a lockstep step on this loaded machine can take
longer than the default 5 periods of wall time, and the controller then
publishes a stand-down zero, which a lockstep plant ignores (the trajectory is
not affected) but the recording would hold at a moment set by the load. The
plant starts once ``pmu`` has its two subscribers (controller and logger) and
then gives the rest of discovery ``discovery_settle_s``: 2 s here (0.2 s by
default), since across the link, under load, the logger's reader of ``/clock``
was once matched 0.9 s of simulated time after the start (it missed the first 47
of 500 ticks; one host: never seen).

Needs root for ``ip netns`` (CI runs as root): without it the tests fail and
say so (test_without_root_the_test_fails_and_says_so shows that they do).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from netns import HOST, network
from nni_msgs_adapter.recording.mcap_io import read_messages
from nni_msgs_adapter.recording.runs import split_topic
from nni_msgs_adapter.ros import command_auth
from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.node_main import FASTDDS_PROFILES_ENV, NETWORK_ENV
from nni_msgs_adapter.ros.processes import node_command
from nni_plant_sim.cases import load_network
from nni_plant_sim.network_plant_node import SUMMARY_PREFIX as NETWORK_SUMMARY
from nni_plant_sim.plant_node import SUMMARY_PREFIX as SMIB_SUMMARY
from rosproc import NodeProcess, busy_processes, fresh_domain_id, ros_env
from test_network_loop import FAULT, controller_parameters
from udp_sniffer import READY, REPORT_PREFIX

pytestmark = pytest.mark.ros

TESTS = Path(__file__).parent
LOGGER = "nni_msgs_adapter.recording.mcap_logger"
CONTROLLER = "nni_battery_controller.controller_node"
RATE_HZ = 50.0
#: Wall-clock watchdog of the controllers, periods (see the module docstring).
STALE_AFTER_PERIODS = 1000
#: The plants' wait, once pmu has its subscribers, for the logger to match their other writers, s (see the docstring).
DISCOVERY_SETTLE_S = 2.0
#: Topics whose recordings must be equal bit for bit (all the logger records but /diagnostics).
NOT_COMPARED = {contract.TOPIC_DIAGNOSTICS}
#: Bytes of the CDR encapsulation header, and of a builtin_interfaces/Time after it.
_CDR_HEADER, _STAMP = 4, 8


@dataclass
class Loop:
    """What runs: the plant (module, parameters, summary prefix) and the controllers (name -> parameters, ros args)."""

    plant: str
    plant_params: dict
    summary_prefix: str
    controllers: dict[str, tuple[dict, tuple]] = field(default_factory=dict)


@dataclass
class Run:
    """What a run left: the recording per topic (CDR bytes in order), the plant's summary, the decoy's report."""

    topics: dict[str, list[bytes]]
    summary: dict
    decoy: dict | None = None
    link_packets: int = 0


def smib_loop() -> Loop:
    plant = {"mode": "lockstep", "duration_s": 10.0, "pmu_rate_hz": RATE_HZ, "wait_for_subscribers": 2,
             "wait_timeout_s": 120.0, "discovery_settle_s": DISCOVERY_SETTLE_S}
    controller = {"battery_limit_pu": 0.3, "sample_rate_hz": RATE_HZ, "stale_after_periods": STALE_AFTER_PERIODS}
    return Loop("nni_plant_sim.plant_node", plant, SMIB_SUMMARY, {"controller": (controller, ())})


def kundur_loop() -> Loop:
    """The Kundur case with a battery of 0.1 pu per generator, bus 7 fault cleared by tripping 7-8 (as test_network_loop)."""
    net = load_network("kundur_two_area")
    plant = {**FAULT, "duration_s": 4.0, "pmu_rate_hz": RATE_HZ, "wait_for_subscribers": 2, "wait_timeout_s": 120.0,
             "discovery_settle_s": DISCOVERY_SETTLE_S}
    controllers = {f"controller_gen{i + 1}": ({**controller_parameters(net, i, 0.1),
                                               "stale_after_periods": STALE_AFTER_PERIODS},
                                              ("-r", f"__ns:=/gen{i + 1}"))
                   for i in range(net.size)}
    return Loop("nni_plant_sim.network_plant_node", plant, NETWORK_SUMMARY, controllers)


def node_env(domain: int, **extra) -> dict:
    """A node's environment: the test's domain, no profile file or network choice inherited from the caller."""
    env = ros_env(domain)
    env.pop(FASTDDS_PROFILES_ENV, None)
    env.pop(NETWORK_ENV, None)
    env.update({name: str(value) for name, value in extra.items()})
    return env


def multihost_env(domain: int, peer: str, discovery_range: str = "LOCALHOST") -> dict:
    """README's "Several hosts" settings, naming ``peer`` (the other host's address)."""
    return node_env(domain, **{NETWORK_ENV: "multihost"}, ROS_AUTOMATIC_DISCOVERY_RANGE=discovery_range,
                    ROS_STATIC_PEERS=peer)


def recorded_topics(mcap: Path) -> dict[str, list[bytes]]:
    """The recording's serialized messages per topic, in order; the invariant set without its header stamp, each
    sealed message (command, measurement, state) without its seal.

    The plant stamps the invariant set, published once before the run, with the wall clock (in
    lockstep too): those 8 bytes (after the 4-byte CDR encapsulation header) are blanked, the rest compared.
    A seal holds a sequence number from its writer's wall clock and a MAC under the run's key, fresh each
    run: it is checked present and blanked (a measurement's mode flag before it is compared).
    """
    marker = f"|{command_auth.SCHEME}|".encode()
    topics: dict[str, list[bytes]] = {}
    for record in read_messages(mcap):
        if record.topic in NOT_COMPARED:
            continue
        cdr = bytes(record.cdr_bytes)
        name = split_topic(record.topic)[1]
        if name == contract.TOPIC_INVARIANT_SET:
            cdr = cdr[:_CDR_HEADER] + bytes(_STAMP) + cdr[_CDR_HEADER + _STAMP:]
        if name in contract.SEALS:
            assert marker in cdr, f"{record.topic}: a message without a seal"
            at = cdr.index(marker) + len(marker)
            if contract.SEALS[name][0] == "measurement":
                at += command_auth.FLAG_LENGTH
            cdr = cdr[:at] + bytes(command_auth.SEAL_LENGTH) + cdr[at + command_auth.SEAL_LENGTH:]
        topics.setdefault(record.topic, []).append(cdr)
    return topics


def run_loop(tmp_path: Path, loop: Loop, hosts=None) -> Run:
    """``loop`` with a logger, on one host (``hosts`` None) or as ``(plant place, its env, controllers' place, env)``.

    Logger and controllers first, then the plant, which waits for them; all ends once the plant has.
    """
    label = "one_host" if hosts is None else "two_hosts"
    mcap = tmp_path / f"{label}.mcap"
    if hosts is None:
        env = node_env(fresh_domain_id())
        plant_place = controller_place = None
        plant_env = controller_env = env
    else:
        plant_place, plant_env, controller_place, controller_env = hosts

    def command(place, argv):
        return argv if place is None else place.command(argv)

    nodes = []
    try:
        nodes.append(NodeProcess(command(controller_place, node_command(LOGGER, {"output_path": str(mcap)})),
                                 controller_env, tmp_path / f"{label}_logger.log"))
        for name, (params, ros_args) in loop.controllers.items():
            nodes.append(NodeProcess(command(controller_place, node_command(CONTROLLER, params, ros_args)),
                                     controller_env, tmp_path / f"{label}_{name}.log"))
        plant = NodeProcess(command(plant_place, node_command(loop.plant, loop.plant_params)), plant_env,
                            tmp_path / f"{label}_plant.log")
        nodes.append(plant)
        assert plant.wait(timeout=240.0) == 0, plant.output()
    finally:
        for node in reversed(nodes):
            node.interrupt(timeout=10.0)
    line = next(line for line in plant.output().splitlines() if line.startswith(loop.summary_prefix))
    return Run(recorded_topics(mcap), json.loads(line[len(loop.summary_prefix):]))


def run_on_two_hosts(tmp_path: Path, loop: Loop, discovery_range: str = "LOCALHOST") -> Run:
    """``loop`` with the plant on host A and the rest on host B; the decoy listens on its links to both."""
    domain = fresh_domain_id()
    with network() as net:
        host_a, host_b, decoy = net.namespace(own_shm=True), net.namespace(own_shm=True), net.namespace()
        end_a, end_b = net.link(host_a, host_b)
        net.link(host_a, decoy)
        net.link(host_b, decoy)
        sniffer = subprocess.Popen(decoy.command([sys.executable, str(TESTS / "udp_sniffer.py")]),
                                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            assert sniffer.stdout.readline().strip() == READY, sniffer.communicate(timeout=10)[0]
            before = end_b.counters()["rx_packets"]
            run = run_loop(tmp_path, loop, (host_a, multihost_env(domain, end_b.address, discovery_range),
                                            host_b, multihost_env(domain, end_a.address, discovery_range)))
            run.link_packets = end_b.counters()["rx_packets"] - before
        finally:
            sniffer.terminate()
            out, _ = sniffer.communicate(timeout=30)
    run.decoy = json.loads(next(line for line in out.splitlines() if line.startswith(REPORT_PREFIX))[len(REPORT_PREFIX):])
    return run


def assert_same_recording(two_hosts: Run, one_host: Run, expected_topics) -> None:
    assert set(one_host.topics) == set(two_hosts.topics) == set(expected_topics), \
        (sorted(one_host.topics), sorted(two_hosts.topics))
    for topic in sorted(expected_topics):
        there, here = two_hosts.topics.get(topic, []), one_host.topics[topic]
        assert len(there) == len(here), (topic, len(there), len(here))
        first = next((k for k, (a, b) in enumerate(zip(there, here)) if a != b), None)
        assert first is None, f"{topic}: message {first} of {len(here)} differs between two hosts and one"


def smib_topics() -> set[str]:
    return {"/" + t for t in (contract.TOPIC_PMU, contract.TOPIC_BATTERY_COMMAND, contract.TOPIC_PLANT_STATE,
                              contract.TOPIC_CONTROLLER_STATE, contract.TOPIC_INVARIANT_SET)} | {contract.TOPIC_CLOCK}


def test_smib_lockstep_with_plant_and_controller_on_two_hosts_equals_the_one_host_run_bit_for_bit(tmp_path):
    loop = smib_loop()
    with busy_processes(2):
        two_hosts = run_on_two_hosts(tmp_path, loop)
        one_host = run_loop(tmp_path, loop)
    samples = int(loop.plant_params["duration_s"] * RATE_HZ)
    assert one_host.summary["measurements"] == one_host.summary["commands"] == samples, one_host.summary
    assert len(one_host.topics["/" + contract.TOPIC_PLANT_STATE]) == samples + 1
    assert_same_recording(two_hosts, one_host, smib_topics())
    for summary in (two_hosts.summary, one_host.summary):
        assert summary["deadline_misses"] == 0 and summary["foreign_commands"] == 0, summary
        assert summary["paired_controller"] == "/controller", summary
    # The measurements crossed the link: host B received at least one datagram per sample from host A.
    assert two_hosts.link_packets >= samples, two_hosts.link_packets
    assert two_hosts.decoy == {}, f"the participants talked on a link they were not meant to use: {two_hosts.decoy}"


def test_kundur_lockstep_with_the_plant_on_one_host_and_four_controllers_on_another_equals_one_host(tmp_path):
    loop = kundur_loop()
    with busy_processes(2):
        two_hosts = run_on_two_hosts(tmp_path, loop)
        one_host = run_loop(tmp_path, loop)
    samples = int(loop.plant_params["duration_s"] * RATE_HZ)
    per_generator = {f"/gen{i}/{t}" for i in range(1, 5) for t in (
        contract.TOPIC_PMU, contract.TOPIC_BATTERY_COMMAND, contract.TOPIC_PLANT_STATE, contract.TOPIC_CONTROLLER_STATE)}
    assert per_generator | {contract.TOPIC_CLOCK} <= set(one_host.topics), sorted(one_host.topics)
    assert_same_recording(two_hosts, one_host, set(one_host.topics))
    for i in range(1, 5):
        assert len(one_host.topics[f"/gen{i}/{contract.TOPIC_PLANT_STATE}"]) == samples + 1
    for summary in (two_hosts.summary, one_host.summary):
        for ns, values in summary.items():
            assert values["deadline_misses"] == 0 and values["samples"] == samples, (ns, values)
            assert values["foreign_commands"] == 0 and values["paired_controller"] == f"/{ns}/controller", values
    assert two_hosts.link_packets >= 4 * samples, two_hosts.link_packets
    assert two_hosts.decoy == {}, f"the participants talked on a link they were not meant to use: {two_hosts.decoy}"


def test_with_ros_default_subnet_discovery_the_decoy_hears_them(tmp_path):
    """The control of the decoy: ROS's default range (SUBNET) multicasts discovery on every interface.

    This is why README's multi-host settings include ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST.
    """
    loop = smib_loop()
    loop.plant_params["duration_s"] = 1.0
    run = run_on_two_hosts(tmp_path, loop, discovery_range="SUBNET")
    assert run.summary["measurements"] == 50, run.summary
    heard = {interface: seen for interface, seen in run.decoy.items() if seen["rtps"] > 0}
    assert len(heard) == 2, run.decoy  # from both hosts, on both of the decoy's links
    assert all(pair[1] == "239.255.0.1" for seen in heard.values() for pair in seen["pairs"]), run.decoy


def test_without_root_the_test_fails_and_says_so(tmp_path):
    """Where ``ip netns`` is not permitted (here: the same helper run without root's capabilities) a test fails.

    The probe keeps uid 0 and drops every capability (``setpriv``), rather than
    running as another user: that user could not read a checkout under a folder
    private to its owner (a clone in a 0700 folder, as ``mktemp -d`` makes), so
    could not even start the venv's python; without CAP_SYS_ADMIN, ``ip netns
    add`` fails as it does for any user who is not root.
    """
    probe = tmp_path / "test_unprivileged.py"
    probe.write_text("from netns import network\n\n\ndef test_needs_a_namespace():\n"
                     "    with network() as net:\n        net.namespace()\n")
    done = subprocess.run(["setpriv", "--bounding-set=-all", "--inh-caps=-all", "--no-new-privs", sys.executable,
                           "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rfs", str(probe)],
                          env={**os.environ, "PYTHONPATH": str(TESTS)}, cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stdout + done.stderr
    assert "1 failed" in done.stdout and "skipped" not in done.stdout, done.stdout
    assert "this test needs root and `ip netns`" in done.stdout, done.stdout
    assert "Operation not permitted" in done.stdout, done.stdout  # refused for want of privilege, not missing


def test_the_network_helper_removes_everything_also_when_the_block_fails():
    """Namespaces, links (also one to this namespace) and shared-memory folders made in a failing block are gone."""
    class Boom(Exception):
        pass

    made = {}
    with pytest.raises(Boom):
        with network() as net:
            a, b = net.namespace(own_shm=True), net.namespace()
            made = {"namespaces": [a.name, b.name], "interfaces": [end.interface for end in net.link(a, b)
                                                                   + net.link(HOST, a)], "shm": a.shm}
            listed = subprocess.run(a.command(["ip", "-o", "-4", "addr", "show"]), capture_output=True, text=True)
            assert "10.213." in listed.stdout and Path(a.shm).is_dir()
            raise Boom
    namespaces = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, check=True).stdout
    links = subprocess.run(["ip", "-o", "link", "show"], capture_output=True, text=True, check=True).stdout
    assert not any(name in namespaces for name in made["namespaces"]), namespaces
    assert not any(f" {interface}@" in links or f" {interface}:" in links for interface in made["interfaces"]), links
    assert not Path(made["shm"]).exists()
