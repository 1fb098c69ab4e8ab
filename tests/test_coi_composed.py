"""The centre-of-inertia reference over the wire and the composed deployment (issue 14, item 2).

Kundur in lockstep, real processes over Fast DDS, the harness of test_network_loop: four controller
nodes with ``reference coi`` (each subscribing to every generator's pmu) must give the offline
``simulate_network(..., reference="coi")``, and the four composed in one process on one executor must
give what four separate processes give, bit for bit.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from nni_battery_controller.controller_config import generator_parameters
from nni_battery_controller.network_deployment import composed_parameters
from nni_battery_controller.network_sim import NetworkLaw, simulate_network
from nni_plant_sim.cases import load_network
from nni_plant_sim.network_scenarios import BusFault
from nni_msgs_adapter.ros import contract
from rosproc import Probe, busy_processes, fresh_domain_id, node_processes, wait_until
from test_network_loop import DURATION_S, RATE_HZ, run_network

pytestmark = pytest.mark.ros

COMPOSED = "nni_battery_controller.composed_controllers"
B = 0.1


@pytest.fixture(scope="module")
def kundur():
    return load_network("kundur_two_area")


def composed(tmp_path):
    """``controllers`` for run_network: one composed_controllers process, a params file with a section per node
    (the deployment's own, ``network_deployment.composed_parameters``)."""
    def start_them(start, parameters: dict) -> None:
        path = tmp_path / "controllers.yaml"
        path.write_text(yaml.safe_dump(composed_parameters({f"/{ns}": values for ns, values in parameters.items()})))
        start("controllers", COMPOSED, {"namespaces": [f"/{ns}" for ns in parameters]}, ("--params-file", str(path)))
    return start_them


def coi_run(tmp_path, net, controllers=None):
    """The lockstep run with reference coi; the plant waits for all five readers of each pmu (4 controllers, probe)."""
    extra = {} if controllers is None else {"controllers": controllers}
    return run_network(tmp_path, net, B, plant_extra={"wait_for_subscribers": net.size + 1},
                       controller_extra=lambda i: generator_parameters(net, i, "coi"), **extra)


@pytest.fixture(scope="module")
def separate_coi_run(tmp_path_factory, kundur):
    """Four controller processes, with two busy processes beside them (discovery of 16 pmu readers under load)."""
    with busy_processes(2):
        return coi_run(tmp_path_factory.mktemp("separate"), kundur)


def test_kundur_lockstep_with_four_coi_controller_processes_equals_the_offline_coi_simulation(kundur,
                                                                                            separate_coi_run):
    """Bus 7 fault cleared at 0.1 s by tripping 7-8, b = 0.1 pu; every generator's state against network_sim's.

    Tolerance 1e-12 absolute, as test_network_loop's (angles ~1 rad, speeds ~1 rad/s). Beyond its
    per-unit bases, the one difference is the order of the arithmetic: offline d_i = (delta_i -
    delta_bar_i) - sum_j w_j (delta_j - delta_bar_j), the controller delta_i - sum_j w_j delta_j -
    reference_angle_rad with the COI-relative pre-fault angle given; an ulp now and then.
    """
    recorded, plant_summary = separate_coi_run
    fault = BusFault(kundur, 7, 0.1, trip=(kundur.bus_model.branch_index(7, 8),))
    offline = simulate_network(kundur, NetworkLaw.uniform(kundur, 0.1, 1.0, 1.1, 1.0, reference="coi"), fault, [B],
                               DURATION_S, RATE_HZ)
    pmu = simulate_network(kundur, NetworkLaw.uniform(kundur, 0.1, 1.0, 1.1, 1.0), fault, [B], DURATION_S, RATE_HZ)
    assert np.abs(offline.delta_rad - pmu.delta_rad).max() > 1e-4, "the test tells the two references apart"
    assert offline.saturated[:-1].any() and not offline.saturated[:-1].all()  # both modes are exercised
    scale = kundur.mbase_mva / kundur.base_mva
    for i, states in enumerate(recorded):
        assert states.shape[0] == offline.t_s.size, f"gen{i + 1}: one plant state per sample, t_0 .. t_n"
        np.testing.assert_allclose(states[:, 1], offline.delta_rad[:, i, 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(states[:, 2], offline.speed_rad_s[:, i, 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(states[:-1, 3], offline.battery_power_pu[:-1, i, 0] / scale[i], rtol=0, atol=1e-12)
    for ns, values in plant_summary.items():
        assert values["deadline_misses"] == 0 and values["samples"] == offline.t_s.size - 1, (ns, values)
        assert values["foreign_commands"] == 0 and values["paired_controller"] == f"/{ns}/controller", values


def test_four_controllers_composed_in_one_process_give_the_separate_processes_trajectory_bit_for_bit(
        tmp_path, kundur, separate_coi_run):
    """Same parameters (per-node sections of one params file), one executor: identical floats at every sample."""
    recorded, plant_summary = coi_run(tmp_path, kundur, composed(tmp_path))
    separate, _ = separate_coi_run
    for i, (states, reference) in enumerate(zip(recorded, separate)):
        assert np.array_equal(states, reference), f"gen{i + 1}"
    for ns, values in plant_summary.items():
        assert values["deadline_misses"] == 0 and values["paired_controller"] == f"/{ns}/controller", values
    log = (tmp_path / "controllers.log").read_text()
    assert "Traceback" not in log, log


def exe(name: str) -> str:
    return str(Path(sys.prefix) / "lib" / "nni_battery_controller" / name)


def test_composed_controllers_help_lists_namespaces_and_the_controller_parameters(tmp_path):
    done = subprocess.run([exe("composed_controllers"), "--help"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("usage: composed_controllers")
    assert "  namespaces [[]]" in lines and "  gain_k [1.0]" in lines and "  reference [pmu]" in lines


@pytest.mark.parametrize("params, sections, expected", [
    ({}, {}, "namespaces is empty"),
    ({"namespaces": ["gen1"]}, {}, "namespaces must be distinct absolute namespaces (/gen1, ...), got ['gen1']"),
    ({"namespaces": ["/gen1", "/gen2"]}, {"/gen2/controller": {"gain_k": 2.0}},
     "/gen2/controller: K must be less than L"),
    ({"namespaces": ["/gen1"]}, {"/gen1/controller": {"reference": "coi", "restoring_power": "measured",
                                                      "reference_angle_rad": 0.1, "coi_namespaces": ["/gen2", "/gen3"],
                                                      "coi_inertias": [1.0, 1.0]}},
     "/gen1/controller: coi_namespaces must include this controller's own namespace /gen1"),
])
def test_a_composed_controller_that_cannot_start_stops_the_process_with_one_line_naming_it(tmp_path, params,
                                                                                         sections, expected):
    path = tmp_path / "controllers.yaml"
    path.write_text(yaml.safe_dump({node: {"ros__parameters": values} for node, values in sections.items()}
                                   or {"/**": {"ros__parameters": {}}}))
    with node_processes(tmp_path, fresh_domain_id()) as start:
        node = start("controllers", COMPOSED, params, ("--params-file", str(path)))
        assert node.wait(timeout=60) == 2
        output = node.output().strip()
    assert output.startswith("composed_controllers: error: ") and expected in output, output
    assert len(output.splitlines()) == 1, output


def test_sigint_stops_every_composed_controller_cleanly(tmp_path):
    """Both nodes report on /diagnostics; on SIGINT each sends its final status and the process exits 0."""
    domain = fresh_domain_id()
    probe = Probe(domain, (contract.TOPIC_DIAGNOSTICS,))

    def reporting(messages) -> set:
        return {status.hardware_id for msg in messages for status in msg.status if status.name.endswith("/controller")}

    try:
        with node_processes(tmp_path, domain) as start:
            node = start("controllers", COMPOSED, {"namespaces": ["/gen1", "/gen2"]})
            names = {"/gen1/controller", "/gen2/controller"}
            assert wait_until(lambda: reporting(probe.take(contract.TOPIC_DIAGNOSTICS)) == names, 60.0), node.output()
            before = len(probe.take(contract.TOPIC_DIAGNOSTICS))
            assert node.interrupt(timeout=15.0) == 0, node.output()
        assert wait_until(lambda: reporting(probe.take(contract.TOPIC_DIAGNOSTICS)[before:]) == names, 5.0)
        assert "Traceback" not in node.output(), node.output()
    finally:
        probe.close()


def test_composed_controllers_read_the_clock_and_the_diagnostics_once_for_the_process(tmp_path):
    """Three controllers in one process: one reader of /clock and one of /diagnostics in the ROS graph, both under
    the host node (each controller's own took every lockstep /clock and every status array once more)."""
    domain = fresh_domain_id()
    probe = Probe(domain, ())

    def readers(topic: str) -> list[str]:
        return sorted(f"{info.node_namespace.rstrip('/')}/{info.node_name}"
                      for info in probe.node.get_subscriptions_info_by_topic(topic))

    try:
        with node_processes(tmp_path, domain) as start:
            node = start("controllers", COMPOSED, {"namespaces": ["/gen1", "/gen2", "/gen3"]})
            pmu = [f"/gen{i}/pmu" for i in (1, 2, 3)]
            assert wait_until(lambda: all(readers(topic) == [f"{topic[:-4]}/controller"] for topic in pmu), 60.0), \
                node.output()
            assert readers(contract.TOPIC_CLOCK) == ["/composed_controllers"]
            assert readers(contract.TOPIC_DIAGNOSTICS) == ["/composed_controllers"]
    finally:
        probe.close()


def test_a_coi_controller_answers_only_complete_stamps_and_says_what_it_could_not_use(tmp_path):
    """Over DDS, /gen1's controller with /gen2 as neighbour (realtime stamps, wall clock).

    A stamp without /gen2's sample is not answered and is given up when the next one is complete
    (coi_incomplete, WARN); once a second writer is on /gen2/pmu its messages are not used (coi_untrusted).
    """
    import time

    from diagnostic_msgs.msg import DiagnosticStatus

    domain = fresh_domain_id()
    params = {"restoring_power": "measured", "reference_angle_rad": 0.1, "p_mech_pu": 0.7, "reference": "coi",
              "coi_namespaces": ["/gen1", "/gen2"], "coi_inertias": [3.0, 1.0],
              # unsealed measurements, so writers are all it can go by (sealed: tests/test_measurement_trust.py)
              "authentication": "none"}
    own = Probe(domain, (contract.TOPIC_BATTERY_COMMAND, contract.TOPIC_DIAGNOSTICS), namespace="gen1")
    neighbour = Probe(domain, (), namespace="gen2", node_name="gen2_pmu")
    rogue = None
    try:
        with node_processes(tmp_path, domain) as start:
            start("controller", "nni_battery_controller.controller_node", params, ("-r", "__ns:=/gen1"))
            assert own.wait_matched(contract.TOPIC_PMU, 1, 60.0) and neighbour.wait_matched(contract.TOPIC_PMU, 1, 60.0)
            stamp = time.time_ns()
            own.publish(contract.TOPIC_PMU, contract.pmu_message(stamp, 0.4, 0.0, 0.7))  # /gen2's never comes
            for probe, delta in ((own, 0.4), (neighbour, 0.8)):
                probe.publish(contract.TOPIC_PMU, contract.pmu_message(stamp + 20_000_000, delta, 0.0, 0.7))
            (command,) = own.wait_for(contract.TOPIC_BATTERY_COMMAND, 1, 10.0)
            d = 0.4 - (0.75 * 0.4 + 0.25 * 0.8) - 0.1  # delta_1 - delta_COI - reference_angle_rad
            assert contract.command_from_message(command) == (stamp + 20_000_000, pytest.approx(-1.1 * d, abs=1e-12))

            rogue = Probe(domain, (), namespace="gen2", node_name="rogue")
            rogue.advertise(contract.TOPIC_PMU)
            assert rogue.wait_matched(contract.TOPIC_PMU, 1, 30.0)  # the rogue's writer matched the controller
            time.sleep(0.5)  # and the controller's reader the rogue (DDS matches both ends within milliseconds)
            for probe in (own, neighbour):
                probe.publish(contract.TOPIC_PMU, contract.pmu_message(stamp + 40_000_000, 0.4, 0.0, 0.7))

            def status():
                found = [s for m in own.take(contract.TOPIC_DIAGNOSTICS) for s in m.status
                         if s.hardware_id == "/gen1/controller"]
                return {kv.key: kv.value for kv in found[-1].values} if found else {}
            assert wait_until(lambda: status().get("coi_untrusted") == "1", 10.0), status()
            assert status()["coi_incomplete"] == "1" and status()["samples"] == "1"
            # Each counter is named once, by the first status after it grew. coi_incomplete grew at the answer:
            # that status is WARN if the 1 Hz tick came within stale_after_s of it, else STALE. coi_untrusted grew
            # 0.5 s later, with no answer since the first: the watchdog had stood down (STALE) by then.
            statuses = [(s.level, s.message) for m in own.take(contract.TOPIC_DIAGNOSTICS) for s in m.status
                        if s.hardware_id == "/gen1/controller"]
            naming = {name: [(level, text) for level, text in statuses if name in text]
                      for name in ("coi_incomplete", "coi_untrusted")}
            assert [len(found) for found in naming.values()] == [1, 1], statuses
            ((level, text),) = naming["coi_incomplete"]
            assert (level, text) in ((DiagnosticStatus.WARN, "centre of inertia: coi_incomplete"),
                                     (DiagnosticStatus.STALE, "STALE; centre of inertia: coi_incomplete"),
                                     (DiagnosticStatus.STALE,  # no tick until both had grown
                                      "STALE; centre of inertia: coi_incomplete, coi_untrusted")), statuses
            ((level, text),) = naming["coi_untrusted"]
            assert level == DiagnosticStatus.STALE and text.startswith("STALE; centre of inertia: "), statuses
            assert all(text.startswith("STALE") for level, text in statuses if level == DiagnosticStatus.STALE)
            commands = [contract.command_from_message(m) for m in own.take(contract.TOPIC_BATTERY_COMMAND)]
            answered = {s for s, _ in commands} & {stamp, stamp + 20_000_000, stamp + 40_000_000}
            assert answered == {stamp + 20_000_000}, "nothing answered from a partial or unattributable sample"
            assert [power for s, power in commands if s not in answered] == [0.0], "the watchdog's one stand-down"
    finally:
        for probe in (own, neighbour, rogue):
            if probe is not None:
                probe.close()
