"""The Kundur network in lockstep over real DDS: one plant process, one controller process per generator (issue 14).

The network plant node integrates the four machines; each controller node runs
in its generator's namespace with g measured (restoring_power measured). The
recorded trajectory must be the offline sampled-data network simulation's.
"""

from __future__ import annotations

import contextlib
import math
import time

import numpy as np
import pytest

from nni_battery_controller.controller_config import generator_parameters
from nni_battery_controller.demo_common import loop_writers, wait_for_recorder
from nni_battery_controller.network_sim import NetworkLaw, NetworkTrajectory, assess_network, simulate_network
from nni_msgs_adapter.ros import contract
from nni_plant_sim.cases import load_network
from nni_plant_sim.network_plant_node import SUMMARY_PREFIX
from nni_plant_sim.network_scenarios import AngleDisplacement, BusFault, MechanicalStep
from rosproc import Probe, busy_processes, fresh_domain_id, node_processes, printed_json, sealed_pmu

pytestmark = pytest.mark.ros

PLANT = "nni_plant_sim.network_plant_node"
CONTROLLER = "nni_battery_controller.controller_node"
RATE_HZ, DURATION_S = 50.0, 4.0
FAULT = {"case": "kundur_two_area", "fault_bus": 7, "clearing_time": 0.1, "trip_line": "7 8"}


@pytest.fixture(scope="module")
def kundur():
    return load_network("kundur_two_area")


def controller_parameters(net, i: int, b: float) -> dict:
    """Generator i's controller: g measured, its pre-fault angle and power (pu of its rating), the default gains."""
    return {**generator_parameters(net, i), "battery_limit_pu": b, "sample_rate_hz": RATE_HZ}


def summary(plant) -> dict:
    return printed_json(plant.output(), SUMMARY_PREFIX)


def separate_controllers(start, parameters: dict) -> None:
    """One controller process per generator, in its namespace (``parameters``: namespace -> its values)."""
    for ns, values in parameters.items():
        start(f"controller_{ns}", CONTROLLER, values, ("-r", f"__ns:=/{ns}"))


def run_network(tmp_path, net, b: float, answering=None, plant_extra=None, controller_extra=None,
                controllers=separate_controllers, disturbance=FAULT):
    """Plant + a controller in each generator's namespace (those in ``answering``, default all); the probes' states.

    ``controller_extra(i)``: more parameters of generator i's controller; ``controllers(start, parameters)``
    starts them (default: one process each).
    """
    domain = fresh_domain_id()
    namespaces = [f"gen{i + 1}" for i in range(net.size)]
    probes = [Probe(domain, (contract.TOPIC_PLANT_STATE, contract.TOPIC_PMU), namespace=ns) for ns in namespaces]
    silent = []
    try:
        with node_processes(tmp_path, domain) as start:
            extra = controller_extra or (lambda i: {})
            controllers(start, {ns: {**controller_parameters(net, i, b), **extra(i)} for i, ns in enumerate(namespaces)
                                if answering is None or i in answering})
            for i, ns in enumerate(namespaces):
                if answering is not None and i not in answering:
                    # a controller that reads the PMU and never answers: the plant pairs with it, times out
                    silent.append(Probe(domain, (contract.TOPIC_PMU,), namespace=ns, node_name="silent_controller"))
                    silent[-1].wait_matched(contract.TOPIC_BATTERY_COMMAND, 0, 0.0)  # makes its writer
            params = {**disturbance, "duration_s": DURATION_S, "pmu_rate_hz": RATE_HZ, "wait_for_subscribers": 2,
                      **(plant_extra or {})}
            plant = start("plant", PLANT, params)
            assert plant.wait(timeout=120.0) == 0, plant.output()
            # One state per reported instant: realtime skips the instants it finds passed (counted), else it
            # would wait out the timeout for every probe (20 s of a loaded suite's 33 s).
            reported = summary(plant)
            states = [probe.wait_for(contract.TOPIC_PLANT_STATE, int(params["duration_s"] * RATE_HZ) + 1
                                     - reported[ns]["skipped_reports"], 5.0) for ns, probe in zip(namespaces, probes)]
            return [np.array([(s * 1e-9, d, w, p) for s, d, w, p in map(contract.plant_state_from_message, rows)])
                    for rows in states], reported
    finally:
        for probe in probes + silent:
            probe.close()


@pytest.mark.parametrize("b, busy", [(0.1, True), (0.0, False)], ids=["batteries_0.1pu_busy", "no_batteries"])
def test_kundur_lockstep_with_four_controller_processes_equals_the_offline_network_simulation(tmp_path, kundur, b,
                                                                                               busy):
    """Bus 7 fault cleared at 0.1 s by tripping 7-8; every generator's recorded state against network_sim's.

    The run with batteries has two busy processes beside it (discovery and the handshake under load).

    Tolerance 1e-12 absolute (angles ~1 rad, speeds ~1 rad/s, as the SMIB's
    lockstep test): the same advance() and the same law.sampled_step as
    offline, float64 carried exactly by CDR; the one difference is the base of
    the powers on the wire (pu of each machine's rating, as for a SMIB, against
    the system base offline): P_E is divided by mbase/base at the plant and the
    command multiplied back, a rounding of an ulp now and then that the
    dynamics carry along (measured over 4 s: 4.4e-16 rad, 2.7e-15 rad/s,
    4.7e-16 pu with batteries; bit for bit without).
    """
    with busy_processes(2) if busy else contextlib.nullcontext():
        recorded, plant_summary = run_network(tmp_path, kundur, b)
    law = NetworkLaw.uniform(kundur, 0.1, 1.0, 1.1, 1.0)
    fault = BusFault(kundur, 7, 0.1, trip=(kundur.bus_model.branch_index(7, 8),))
    offline = simulate_network(kundur, law, fault, [b], DURATION_S, RATE_HZ)
    scale = kundur.mbase_mva / kundur.base_mva
    if b > 0:
        assert offline.saturated[:-1].any() and not offline.saturated[:-1].all()  # both modes are exercised
    for i, states in enumerate(recorded):
        assert states.shape[0] == offline.t_s.size, f"gen{i + 1}: one plant state per sample, t_0 .. t_n"
        np.testing.assert_allclose(states[:, 0], offline.t_s, rtol=0, atol=1e-9)
        np.testing.assert_allclose(states[:, 1], offline.delta_rad[:, i, 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(states[:, 2], offline.speed_rad_s[:, i, 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(states[:-1, 3], offline.battery_power_pu[:-1, i, 0] / scale[i], rtol=0, atol=1e-12)
    for ns, values in plant_summary.items():
        assert values["deadline_misses"] == 0 and values["samples"] == offline.t_s.size - 1, (ns, values)
        assert values["foreign_commands"] == 0 and values["paired_controller"].endswith(f"/{ns}/controller"), values


def offline_disturbance(net, name: str):
    """The offline scenario that the plant parameters of test_kundur_lockstep_scenarios describe, built directly."""
    if name == "mechanical_step":  # G2 (bus 2) at 0.95 pu of its rating for 0.5 s
        return MechanicalStep(1, 0.95 * float(net.mbase_mva[1] / net.base_mva), 0.5)
    return AngleDisplacement(np.array([0.3, 0.0, 0.3, 0.0]))  # G1 and G3 (buses 1, 3) 0.3 rad ahead


@pytest.mark.parametrize("name, disturbance", [
    ("mechanical_step", {"scenario": "mechanical_step", "machine": [2], "step_p_mech": 0.95, "step_duration": 0.5}),
    ("angle_displacement", {"scenario": "angle_displacement", "machine": [1, 3], "displace": 0.3}),
])
def test_kundur_lockstep_scenarios_with_the_offline_option_names_equal_the_offline_simulation(tmp_path, kundur, name,
                                                                                              disturbance):
    """The network plant's mechanical_step and angle_displacement, b = 0.1 pu: network_sim's trajectory (1e-12).

    The tolerance is that of the bus fault above (the same advance(), law and base conversion).
    """
    recorded, plant_summary = run_network(tmp_path, kundur, 0.1, disturbance=disturbance)
    law = NetworkLaw.uniform(kundur, 0.1, 1.0, 1.1, 1.0)
    offline = simulate_network(kundur, law, offline_disturbance(kundur, name), [0.1], DURATION_S, RATE_HZ)
    scale = kundur.mbase_mva / kundur.base_mva
    assert np.ptp(offline.delta_rad[:, :, 0], axis=0).min() > 1e-3, "every machine moves"
    for i, states in enumerate(recorded):
        assert states.shape[0] == offline.t_s.size, f"gen{i + 1}: one plant state per sample, t_0 .. t_n"
        np.testing.assert_allclose(states[:, 1], offline.delta_rad[:, i, 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(states[:, 2], offline.speed_rad_s[:, i, 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(states[:-1, 3], offline.battery_power_pu[:-1, i, 0] / scale[i], rtol=0, atol=1e-12)
    assert all(values["deadline_misses"] == 0 for values in plant_summary.values()), plant_summary


def test_a_generator_whose_controller_never_answers_times_out_alone_and_the_run_ends(tmp_path, kundur):
    """gen4's only writer never answers: each of its samples times out (counted for gen4 only), zero power there.

    The timeout (0.25 s of wall time) is generous: a loaded machine once kept an answering controller 50 ms.
    """
    recorded, plant_summary = run_network(tmp_path, kundur, 0.1, answering=(0, 1, 2),
                                          plant_extra={"lockstep_timeout_s": 0.25, "duration_s": 0.4})
    samples = int(0.4 * RATE_HZ)
    assert plant_summary["gen4"]["deadline_misses"] == samples
    assert [plant_summary[f"gen{i}"]["deadline_misses"] for i in (1, 2, 3)] == [0, 0, 0]
    assert np.all(recorded[3][:, 3] == 0.0) and np.any(recorded[0][:, 3] != 0.0)


@pytest.mark.parametrize("params, expected", [
    ({"fault_bus": 99}, "bus 99 is not in the case (buses 1..11)"),
    ({"trip_line": "7 to 8"}, "trip_line takes 'FROM TO [CIRCUIT]', got '7 to 8'"),
    ({"scenario": "line_trip", "trip_line": "7 8", "clearing_time": 0.2},
     "not for scenario line_trip: clearing_time (bus_fault only)"),
    ({"scenario": "line_trip"}, "scenario line_trip needs trip_line"),
    ({"machine": [2]}, "not for scenario bus_fault: machine (mechanical_step, angle_displacement only)"),
    ({"scenario": "mechanical_step", "machine": [2], "displace": 0.3, "trip_line": "7 8"},
     "not for scenario mechanical_step: trip_line (bus_fault, line_trip only), displace (angle_displacement only)"),
    ({"scenario": "angle_displacement", "displace": 0.3}, "scenario angle_displacement needs machine (generator bus "
                                                          "numbers)"),
    ({"scenario": "mechanical_step", "machine": [1, 2]}, "scenario mechanical_step needs one machine, got [1, 2]"),
    ({"scenario": "angle_displacement", "machine": [1, 5]},
     "machine 5: no generator at that bus (generators at 1, 2, 3, 4)"),
])
def test_a_network_plant_parameter_that_cannot_work_is_refused_with_one_line(tmp_path, params, expected):
    domain = fresh_domain_id()
    with node_processes(tmp_path, domain) as start:
        plant = start("plant", PLANT, params)
        assert plant.wait(timeout=60.0) == 2
        assert plant.output().strip() == f"network_plant_node: error: {expected}"


def test_runtime_changes_are_rejected_with_their_reason(tmp_path):
    """The network plant reads every parameter at start; a controller refuses reference_angle_rad in model mode."""
    from rclpy.parameter import Parameter
    from test_node_parameters import _call, parameter_client

    domain = fresh_domain_id()
    with node_processes(tmp_path, domain) as start:
        start("plant", PLANT, {"wait_for_subscribers": 1, "allow_tuning": True})
        start("controller", CONTROLLER, {"allow_tuning": True}, ("-r", "__ns:=/gen1"))
        plant, close_plant = parameter_client(domain, "network_plant")
        controller, close_controller = parameter_client(domain, "/gen1/controller")
        try:
            assert plant.wait_for_services(timeout_sec=20.0) and controller.wait_for_services(timeout_sec=20.0)
            bus = _call(lambda: plant.set_parameters([Parameter("fault_bus", value=8)])).results[0]
            assert not bus.successful and bus.reason == "fault_bus cannot change once the node is up (read at start)"
            assert _call(lambda: plant.get_parameters(["fault_bus"])).values[0].integer_value == 7
            angle = _call(lambda: controller.set_parameters([Parameter("reference_angle_rad", value=0.3)])).results[0]
            assert not angle.successful and "applies to restoring_power measured only" in angle.reason
            both = _call(lambda: controller.set_parameters_atomically([Parameter("restoring_power", value="measured"),
                                                               Parameter("reference_angle_rad", value=0.3)]))
            assert both.result.successful, both.result.reason  # before a run: measured mode with its angle
        finally:
            close_plant()
            close_controller()


@pytest.mark.parametrize("clearing_s", [0.1, 0.2])
def test_kundur_realtime_with_four_controller_processes_gives_the_offline_verdict(tmp_path, kundur, clearing_s):
    """Realtime at 50 frames/s, b = 0.1 pu: in synchronism (cleared at 0.1 s) or not (0.2 s) as network_sim says.

    In realtime a command acts from its arrival (about a millisecond after its
    measurement's instant), not from the instant: the trajectories differ a
    little, the verdict must not; a loss of synchronism is found within 0.1 s
    of the offline one. Two busy processes run beside it.
    """
    duration = 3.0
    with busy_processes(2):
        recorded, plant_summary = run_network(tmp_path, kundur, 0.1, plant_extra={
            "mode": "realtime", "clearing_time": clearing_s, "duration_s": duration})
    law = NetworkLaw.uniform(kundur, 0.1, 1.0, 1.1, 1.0)
    fault = BusFault(kundur, 7, clearing_s, trip=(kundur.bus_model.branch_index(7, 8),))
    offline = assess_network(simulate_network(kundur, law, fault, [0.1], duration, RATE_HZ))[0]
    stamps = [states[:, 0] for states in recorded]
    assert all(np.array_equal(s, stamps[0]) for s in stamps), "every generator reports at the same instants"
    t = stamps[0] - stamps[0][0]
    shape = (t.size, kundur.size, 1)
    delta = np.stack([states[:, 1] for states in recorded], axis=1)[:, :, None]
    speed = np.stack([states[:, 2] for states in recorded], axis=1)[:, :, None]
    power = np.stack([states[:, 3] for states in recorded], axis=1)[:, :, None]  # pu of each machine's rating
    system_base = power * (kundur.mbase_mva / kundur.base_mva)[None, :, None]
    limits = kundur.pu_of_machine(np.full(kundur.size, 0.1))[:, None]
    realtime = assess_network(NetworkTrajectory(kundur, t, delta, speed, system_base, np.zeros(shape),
                                                np.zeros(shape, bool), limits))[0]
    assert realtime.in_synchronism == offline.in_synchronism == (clearing_s < 0.15)
    assert [g.in_synchronism for g in realtime.generators] == [g.in_synchronism for g in offline.generators]
    if not offline.in_synchronism:
        assert abs(realtime.pole_slip_s - offline.pole_slip_s) <= 0.1
    assert np.all(np.abs(power) <= 0.1 + 1e-12)  # |P_ST,i| <= b_i at every reported instant
    assert all(values["mode"] == "realtime" and values["measurements"] > 0 for values in plant_summary.values())


def test_the_mcap_logger_records_every_generator_of_the_network_run(tmp_path, kundur):
    """One logger, lockstep with batteries: the file holds /gen1../gen4, each equal to network_sim (1e-12)."""
    import signal

    from nni_msgs_adapter.recording.runs import read_generator_runs

    domain, path, b = fresh_domain_id(), tmp_path / "network.mcap", 0.1
    with node_processes(tmp_path, domain) as start:
        logger = start("logger", "nni_msgs_adapter.recording.mcap_logger", {"output_path": str(path), "discovery_period_s": 0.1})
        for i in range(kundur.size):
            start(f"controller_gen{i + 1}", CONTROLLER, controller_parameters(kundur, i, b), ("-r", f"__ns:=/gen{i + 1}"))
        plant = start("plant", PLANT, {**FAULT, "duration_s": DURATION_S, "pmu_rate_hz": RATE_HZ,
                                       "wait_for_subscribers": 2, "hold_until_released": True})
        # Released once the logger has matched every loop writer, as nni-demo does: the plant's count of two
        # readers on each pmu cannot tell whether the logger's plant/state readers have matched too (a loaded
        # suite once recorded the states from 2.26 s on).
        wait_for_recorder(logger, loop_writers([f"gen{i + 1}" for i in range(kundur.size)],
                                               lambda ns: f"/{ns}/controller", "/network_plant"), tmp_path)
        plant.proc.send_signal(signal.SIGUSR1)
        assert plant.wait(timeout=120.0) == 0, plant.output()
        time.sleep(0.5)  # the last reliable messages land
        logger.proc.send_signal(signal.SIGINT)
        assert logger.proc.wait(timeout=15) == 0, logger.output()
    runs = read_generator_runs(path)
    assert list(runs) == [f"/gen{i + 1}" for i in range(kundur.size)]
    law = NetworkLaw.uniform(kundur, 0.1, 1.0, 1.1, 1.0)
    fault = BusFault(kundur, 7, 0.1, trip=(kundur.bus_model.branch_index(7, 8),))
    offline = simulate_network(kundur, law, fault, [b], DURATION_S, RATE_HZ)
    for i, run in enumerate(runs.values()):
        np.testing.assert_allclose(run.stamp_ns * 1e-9, offline.t_s, rtol=0, atol=1e-9)
        np.testing.assert_allclose(run.delta_rad, offline.delta_rad[:, i, 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(run.speed_rad_s, offline.speed_rad_s[:, i, 0], rtol=0, atol=1e-12)
        assert run.battery_limit_pu == b and run.diagnostics["machine"] == kundur.names[i]


def test_a_controller_with_g_measured_answers_from_the_pmus_power_and_counts_what_it_cannot_use(tmp_path):
    """At the reference angle with x3 = 0 the command is -g = P_E - P_M; no P_E is malformed, NaN non-finite."""
    domain = fresh_domain_id()
    topics = (contract.TOPIC_BATTERY_COMMAND, contract.TOPIC_DIAGNOSTICS)
    with node_processes(tmp_path, domain) as start:
        start("controller", CONTROLLER, {"restoring_power": "measured", "reference_angle_rad": 0.3,
                                         "p_mech_pu": 0.7, "battery_limit_pu": 0.3})
        probe = Probe(domain, topics)
        try:
            assert probe.wait_matched(contract.TOPIC_PMU, 1, 30.0)
            stamp = time.time_ns()
            no_power = contract.pmu_message(stamp + 1, 0.3, 0.0, 0.0)
            no_power.effort = []
            for msg in (contract.pmu_message(stamp, 0.3, 0.0, 0.65), no_power,
                        contract.pmu_message(stamp + 2, 0.3, 0.0, math.nan),
                        contract.pmu_message(stamp + 3, 0.3, 0.0, 0.9)):
                probe.publish(contract.TOPIC_PMU, sealed_pmu(msg))  # as the plant would: its shape is the test
            commands = [contract.command_from_message(m) for m in probe.wait_for(contract.TOPIC_BATTERY_COMMAND, 2, 10.0)]
            assert commands[0] == (stamp, pytest.approx(0.65 - 0.7, abs=1e-15))  # w = x3 - L*0 - (P_M - P_E)
            assert commands[1] == (stamp + 3, pytest.approx(0.9 - 0.7, abs=1e-15))  # d = 0 kept x3 at 0
            deadline, values = time.monotonic() + 5.0, None
            while values is None and time.monotonic() < deadline:  # the status once both samples are counted
                time.sleep(0.05)
                values = next((v for m in probe.take(contract.TOPIC_DIAGNOSTICS)
                               if (v := contract.diagnostic_values(m, "controller")) is not None
                               and v["samples"] == "2"), None)
            assert (values["malformed"], values["non_finite"]) == ("1", "1")
        finally:
            probe.close()


def test_with_fault_at_start_false_the_network_waits_for_the_start_fault_service(tmp_path, kundur):
    """Realtime: at rest on the pre-fault equilibrium until plant/start_fault; the fault from then; once only."""
    from std_srvs.srv import Trigger
    from test_node_parameters import _call

    domain, b = fresh_domain_id(), 0.1
    probes = [Probe(domain, (contract.TOPIC_PLANT_STATE, contract.TOPIC_PMU), namespace=f"gen{i + 1}")
              for i in range(kundur.size)]  # on the pmu too: the plant starts once they listen
    try:
        with node_processes(tmp_path, domain) as start:
            for i in range(kundur.size):
                start(f"controller_gen{i + 1}", CONTROLLER, controller_parameters(kundur, i, b),
                      ("-r", f"__ns:=/gen{i + 1}"))
            plant = start("plant", PLANT, {**FAULT, "mode": "realtime", "duration_s": 3.0, "pmu_rate_hz": RATE_HZ,
                                           "fault_at_start": False, "wait_for_subscribers": 2})
            client = probes[0].node.create_client(Trigger, "/" + contract.SERVICE_START_FAULT)
            assert client.wait_for_service(timeout_sec=60.0)
            # 1 s of rest: the states of t = 0 .. 1.0 s (RATE_HZ + 1 of them)
            assert len(probes[0].wait_for(contract.TOPIC_PLANT_STATE, int(RATE_HZ) + 1, 60.0)) >= RATE_HZ + 1
            first = _call(client.call_async(Trigger.Request()))
            again = _call(client.call_async(Trigger.Request()))
            assert plant.wait(timeout=60.0) == 0, plant.output()
            reported = summary(plant)  # one state per reported instant (realtime skips those found passed)
            states = [probe.wait_for(contract.TOPIC_PLANT_STATE, int(3.0 * RATE_HZ) + 1
                                     - reported[f"gen{i + 1}"]["skipped_reports"], 5.0)
                      for i, probe in enumerate(probes)]
    finally:
        for probe in probes:
            probe.close()
    assert first.success and first.message.startswith("fault started at t = "), first.message
    assert not again.success and again.message == "the fault has already started"
    fault_s = float(first.message.split("= ")[1].split()[0])
    assert fault_s >= 1.0
    for i, rows in enumerate(states):
        stamp, delta, speed, _ = np.array([contract.plant_state_from_message(m) for m in rows]).T
        before = (stamp - stamp[0]) * 1e-9 <= fault_s
        np.testing.assert_allclose(delta[before], kundur.delta_bar_rad[i], rtol=0, atol=1e-9)
        np.testing.assert_allclose(speed[before], 0.0, rtol=0, atol=1e-9)
        assert np.abs(speed[~before]).max() > 1e-3, f"gen{i + 1}: the fault moves the machine"


def test_pmu_noise_is_drawn_per_generator_from_its_own_seed(tmp_path, kundur):
    """Angle noise 0.01 rad, noise_seed 5: generator i's measured minus true angles are the normal draws of seed 4 + i."""
    domain, std, seed = fresh_domain_id(), 0.01, 5
    topics = (contract.TOPIC_PMU, contract.TOPIC_PLANT_STATE)
    probes = [Probe(domain, topics, namespace=f"gen{i + 1}") for i in range(kundur.size)]
    try:
        with node_processes(tmp_path, domain) as start:
            for i in range(kundur.size):
                start(f"controller_gen{i + 1}", CONTROLLER, controller_parameters(kundur, i, 0.1),
                      ("-r", f"__ns:=/gen{i + 1}"))
            plant = start("plant", PLANT, {**FAULT, "duration_s": 1.0, "pmu_rate_hz": RATE_HZ, "wait_for_subscribers": 2,
                                           "noise_angle_std_rad": std, "noise_seed": seed})
            assert plant.wait(timeout=120.0) == 0, plant.output()
            n = int(RATE_HZ)
            runs = [(probe.wait_for(contract.TOPIC_PMU, n, 5.0), probe.wait_for(contract.TOPIC_PLANT_STATE, n + 1, 5.0))
                    for probe in probes]
    finally:
        for probe in probes:
            probe.close()
    for i, (pmu, states) in enumerate(runs):
        measured = np.array([contract.pmu_from_message(m)[1:] for m in pmu])
        true = np.array([contract.plant_state_from_message(m)[1:3] for m in states[:n]])
        draws = np.random.default_rng(seed + i).normal(0.0, std, n)
        np.testing.assert_allclose(measured[:, 0] - true[:, 0], draws, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(measured[:, 1], true[:, 1])  # no speed noise asked for
