"""Fault injection: bad input, stale data, dying and restarting processes, over real DDS.

Measurement faults are injected by a test publisher on ``pmu`` (a real DDS
publisher in the test process, standing in for a faulty PMU); process faults by
SIGKILL on real node processes.
"""

from __future__ import annotations

import math
import signal
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from nni_battery_controller.law import ControllerParams, SampledController
from nni_msgs_adapter.ros import contract
from nni_plant_sim.model import SmibParams
from rosproc import Probe, fresh_domain_id, node_processes, sealed_pmu, wait_until

pytestmark = pytest.mark.ros

CONTROLLER = "nni_battery_controller.controller_node"
PLANT = "nni_plant_sim.plant_node"
LOGGER = "nni_msgs_adapter.recording.mcap_logger"
DELTA_BAR = SmibParams().delta_bar_rad

# --- the battery limit is an invariant: the core -------------------------------------------

ANY_FLOAT = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-10.0, max_value=10.0),
    st.sampled_from([1e308, -1e308, 5e-324, math.pi, -math.pi]),
)


@settings(max_examples=3000, deadline=None)
@given(b=st.one_of(st.floats(min_value=0.0, max_value=5.0), st.just(0.0)),
       measurements=st.lists(ANY_FLOAT, min_size=1, max_size=20))
def test_core_command_never_exceeds_b(b, measurements):
    """Whatever arrives, the sampled law's command is finite and within +-b."""
    law = SampledController(SmibParams(), ControllerParams(battery_limit_pu=b), 0.02)
    for angle_dev in measurements:
        if not math.isfinite(angle_dev):
            with pytest.raises(ValueError):
                law.step(angle_dev)
            continue
        power, _, _ = law.step(angle_dev)
        assert math.isfinite(power) and abs(power) <= b
        assert math.isfinite(law.x3)


def test_negative_b_is_rejected_at_configuration():
    with pytest.raises(ValueError, match="b must be non-negative"):
        ControllerParams(battery_limit_pu=-1e-9)


# --- the battery limit is an invariant: the controller node's input path --------------------


@pytest.fixture(scope="module")
def controller_under_test(tmp_path_factory):
    """A controller process (b = 0.3, stale detection out of the way) and a probe on its topics."""
    tmp_path = tmp_path_factory.mktemp("controller")
    domain = fresh_domain_id()
    with node_processes(tmp_path, domain) as start:
        # A generous stamp tolerance: the duplicate and out-of-order samples below reuse a stamp taken before
        # a wait for diagnostics (up to 1 s); stamp plausibility has its own tests (test_input_gate.py).
        start("controller", CONTROLLER, {"battery_limit_pu": 0.3, "stale_after_periods": 10000,
                                         "stamp_tolerance_s": 60.0})
        probe = Probe(domain, (contract.TOPIC_BATTERY_COMMAND, contract.TOPIC_CONTROLLER_STATE,
                               contract.TOPIC_DIAGNOSTICS))
        assert probe.wait_matched(contract.TOPIC_PMU, 1, 30.0)
        try:
            # [last stamp used, last stamp answered], shared across examples: stamps must grow, and stay
            # near the controller's clock (wall time), else they are implausible.
            yield probe, [time.time_ns()] * 2
        finally:
            probe.close()


def next_stamp(last_ns: int) -> int:
    """A stamp after ``last_ns`` and no earlier than now (the controller checks stamps against its clock)."""
    return max(last_ns + 1_000_000, time.time_ns())


def answers_for(probe, stamp_ns: int, timeout: float = 5.0):
    """The command answering ``stamp_ns`` (waits for it), or None."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for msg in reversed(probe.take(contract.TOPIC_BATTERY_COMMAND)):
            if contract.ns_from_time(msg.header.stamp) == stamp_ns:
                return msg
        time.sleep(0.002)
    return None


FAULTY_SAMPLE = st.one_of(
    st.tuples(st.just("valid"), st.floats(min_value=-50.0, max_value=50.0)),
    st.tuples(st.just("valid"), st.sampled_from([1e5, -1e5, 0.0, DELTA_BAR])),
    st.tuples(st.just("nonfinite"), st.sampled_from([math.nan, math.inf, -math.inf])),
    st.tuples(st.just("implausible"), st.sampled_from([1e308, -1e308, 1e7])),
    st.tuples(st.just("duplicate"), st.just(0.0)),
    st.tuples(st.just("out_of_order"), st.just(0.0)),
)


# Each example costs real DDS round trips: no shrinking (it would take minutes); the
# failing example is printed whole.
@settings(max_examples=25, deadline=None, phases=[Phase.explicit, Phase.reuse, Phase.generate],
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(samples=st.lists(FAULTY_SAMPLE, min_size=20, max_size=80))
def test_node_commands_stay_within_b_whatever_arrives(controller_under_test, samples):
    """Over DDS: every answer is finite and within +-b; faulty samples get no answer at all."""
    probe, last_stamp = controller_under_test
    answered, dropped = [], []
    for kind, value in samples:
        if kind == "duplicate":
            stamp = last_stamp[1]  # the stamp of the last answered measurement
        elif kind == "out_of_order":
            stamp = last_stamp[1] - 1_000_000
        else:
            last_stamp[0] = stamp = next_stamp(last_stamp[0])
        delta = value + DELTA_BAR if kind == "valid" else value
        probe.publish(contract.TOPIC_PMU, sealed_pmu(contract.pmu_message(stamp, delta, 0.0, 0.0)))
        if kind == "valid":
            answered.append(stamp)
            last_stamp[1] = stamp
            assert answers_for(probe, stamp) is not None, "a valid measurement was not answered"
        elif kind in ("nonfinite", "implausible"):
            dropped.append(stamp)
    commands = probe.take(contract.TOPIC_BATTERY_COMMAND)
    for msg in commands:
        _, power = contract.command_from_message(msg)
        assert math.isfinite(power) and abs(power) <= 0.3
    answered_stamps = {contract.ns_from_time(m.header.stamp) for m in commands}
    assert not answered_stamps & set(dropped), "a dropped measurement was answered"


def test_dropped_inputs_are_counted_in_diagnostics(controller_under_test):
    probe, last_stamp = controller_under_test

    def counts_after_barrier():
        """Counters from a diagnostics message sent after every earlier sample was handled."""
        last_stamp[0] = last_stamp[1] = next_stamp(last_stamp[0])
        probe.publish(contract.TOPIC_PMU, sealed_pmu(contract.pmu_message(last_stamp[0], DELTA_BAR, 0.0, 0.0)))
        assert answers_for(probe, last_stamp[0]) is not None  # everything before it was handled
        seen = len(probe.take(contract.TOPIC_DIAGNOSTICS))
        assert wait_until(lambda: any(contract.diagnostic_values(m, "controller") is not None
                                      for m in probe.take(contract.TOPIC_DIAGNOSTICS)[seen:]), 5.0)
        for msg in probe.take(contract.TOPIC_DIAGNOSTICS)[seen:]:
            values = contract.diagnostic_values(msg, "controller")
            if values is not None:
                return {k: int(values[k]) for k in COUNTERS}

    before = counts_after_barrier()
    base = last_stamp[0]
    for delta, stamp in ((math.nan, base + 1), (DELTA_BAR, base), (DELTA_BAR, base - 5), (1e9, base + 2)):
        probe.publish(contract.TOPIC_PMU, sealed_pmu(contract.pmu_message(stamp, delta, 0.0, 0.0)))
    malformed = sealed_pmu(contract.pmu_message(base + 3, DELTA_BAR, 0.0, 0.0))  # sealed, then another shape
    malformed.name = ["rotor", "extra"]
    probe.publish(contract.TOPIC_PMU, malformed)
    after = counts_after_barrier()
    assert {k: after[k] - before[k] for k in COUNTERS} == {
        "samples": 1, "non_finite": 1, "duplicate": 1, "out_of_order": 1, "implausible": 1, "malformed": 0,
        "unauthenticated_measurements": 1}  # a message the contract cannot read cannot be tied to the plant


COUNTERS = ("samples", "malformed", "non_finite", "duplicate", "out_of_order", "implausible",
            "unauthenticated_measurements")


# --- stale data ----------------------------------------------------------------------------


def test_stale_data_zero_power_then_clean_resume(tmp_path):
    """No data for 5 periods: one zero command and STALE; data back: state reset, no jump."""
    domain = fresh_domain_id()
    b, rate = 0.3, 50.0
    with node_processes(tmp_path, domain) as start:
        start("controller", CONTROLLER, {"battery_limit_pu": b, "sample_rate_hz": rate, "stale_after_periods": 5})
        probe = Probe(domain, (contract.TOPIC_BATTERY_COMMAND, contract.TOPIC_CONTROLLER_STATE,
                               contract.TOPIC_DIAGNOSTICS))
        try:
            assert probe.wait_matched(contract.TOPIC_PMU, 1, 30.0)
            angle_dev = -0.5  # far from equilibrium: x3 moves away from 0 quickly
            stamp = time.time_ns()
            for _ in range(20):
                probe.publish(contract.TOPIC_PMU, sealed_pmu(contract.pmu_message(stamp, angle_dev + DELTA_BAR, 0.0, 0.0)))
                assert answers_for(probe, stamp) is not None
                stamp += 20_000_000
                time.sleep(0.02)
            x3_before_gap = contract.controller_state_from_message(
                probe.wait_for(contract.TOPIC_CONTROLLER_STATE, 20, 5.0)[-1])[1]["x3"]
            assert abs(x3_before_gap) > 0.05
            n_commands = len(probe.take(contract.TOPIC_BATTERY_COMMAND))
            time.sleep(1.2)  # > 5 periods (0.1 s), and a diagnostics period
            after_gap = probe.take(contract.TOPIC_BATTERY_COMMAND)[n_commands:]
            assert [contract.command_from_message(m)[1] for m in after_gap] == [0.0], "one zero command"
            # Stamped when the silence was noticed: never before 5 periods, and not a second watchdog period late.
            noticed_after_ns = contract.command_from_message(after_gap[0])[0] - (stamp - 20_000_000)
            assert 100_000_000 <= noticed_after_ns < 190_000_000
            statuses = [contract.diagnostic_values(m, "controller") is not None and m.status[0].message
                        for m in probe.take(contract.TOPIC_DIAGNOSTICS)]
            assert "STALE" in statuses
            stamp = time.time_ns()  # data returns after a gap of > 5 periods in its own stamps
            probe.publish(contract.TOPIC_PMU, sealed_pmu(contract.pmu_message(stamp, angle_dev + DELTA_BAR, 0.0, 0.0)))
            resumed = answers_for(probe, stamp)
            assert resumed is not None
            fresh = SampledController(SmibParams(), ControllerParams(battery_limit_pu=b), 1.0 / rate)
            expected_power, _, _ = fresh.step(angle_dev)
            assert contract.command_from_message(resumed)[1] == pytest.approx(expected_power, abs=1e-12)
            state = [contract.controller_state_from_message(m) for m in
                     probe.wait_for(contract.TOPIC_CONTROLLER_STATE, 21, 5.0)]
            assert state[-1][0] == stamp and state[-1][1]["x3"] == 0.0, "state reset when data resumed"
        finally:
            probe.close()


def implausible(probe) -> int:
    """The controller's ``implausible_stamp`` count in its latest diagnostics the probe has heard."""
    counts = [contract.diagnostic_values(m, "controller") for m in probe.take(contract.TOPIC_DIAGNOSTICS)]
    return int([c for c in counts if c is not None][-1]["implausible_stamp"])


def test_without_authentication_in_lockstep_the_controller_checks_each_stamp_against_the_latest_clock_heard(tmp_path):
    """authentication none: the controller reads /clock when a measurement comes (no callback of its own): a stamp
    within stamp_tolerance_s (1 s) of the newest /clock is answered, one 100 s ahead of it is not. (With
    authentication hmac it takes no time from /clock: tests/test_measurement_trust.py.)"""
    from rosgraph_msgs.msg import Clock

    domain = fresh_domain_id()
    with node_processes(tmp_path, domain) as start:
        start("controller", CONTROLLER, {"battery_limit_pu": 0.3, "stale_after_periods": 10000,
                                         "authentication": "none"})
        probe = Probe(domain, (contract.TOPIC_BATTERY_COMMAND, contract.TOPIC_DIAGNOSTICS))
        try:
            assert probe.wait_matched(contract.TOPIC_PMU, 1, 30.0) and probe.wait_matched(contract.TOPIC_CLOCK, 1, 30.0)

            def clock(seconds: float) -> None:
                probe.publish(contract.TOPIC_CLOCK, Clock(clock=contract.time_from_ns(round(seconds * 1e9))))
                time.sleep(0.3)  # delivered before the measurement that follows

            def answered(seconds: float) -> bool:
                stamp = round(seconds * 1e9)
                probe.publish(contract.TOPIC_PMU, contract.pmu_message(stamp, DELTA_BAR, 0.0, 0.0))
                return answers_for(probe, stamp, timeout=1.5) is not None

            # Both directions matched before anything is judged: the probe's publishers have matched the
            # controller's readers, but the controller's command writer may not yet have matched the probe's
            # reader (on a clean clone the first answer was lost so). The first answered measurement proves it.
            clock(50.0)
            assert any(answered(50.0 + 0.02 * k) for k in range(1, 11)), "the controller never answered"
            # What the warm-up cost is not judged: under load the first /clock tick can reach the controller after
            # the first measurement, which is then implausible against no clock (a clean clone once counted 2).
            time.sleep(1.2)
            warm_up = implausible(probe)
            clock(100.0)
            assert answered(100.02)
            assert not answered(200.0), "100 s ahead of /clock: implausible"
            clock(150.0)
            clock(199.98)
            assert answered(200.02), "against the newest /clock, not the first one since the last measurement"
            time.sleep(1.2)
            judged = implausible(probe) - warm_up
        finally:
            probe.close()
    assert judged == 1, "exactly the measurement 100 s ahead of /clock"


# --- process faults ------------------------------------------------------------------------


def plant_diagnostics(probe):
    """The latest plant diagnostics values, or {}."""
    for msg in reversed(probe.take(contract.TOPIC_DIAGNOSTICS)):
        values = contract.diagnostic_values(msg, "plant")
        if values is not None:
            return values
    return {}


def test_killed_controller_times_out_to_zero_and_a_restart_recovers(tmp_path):
    domain = fresh_domain_id()
    with node_processes(tmp_path, domain) as start:
        probe = Probe(domain, (contract.TOPIC_PLANT_STATE, contract.TOPIC_DIAGNOSTICS,
                               contract.TOPIC_BATTERY_COMMAND))
        try:
            controller = start("controller", CONTROLLER, {"battery_limit_pu": 0.3})
            plant = start("plant", PLANT, {"mode": "realtime", "wait_for_subscribers": 1})
            assert wait_until(lambda: len(probe.take(contract.TOPIC_BATTERY_COMMAND)) > 25, 30.0)
            controller.kill()
            killed_at = len(probe.take(contract.TOPIC_PLANT_STATE))
            assert wait_until(lambda: int(plant_diagnostics(probe).get("command_timeouts", 0)) >= 1, 5.0)
            time.sleep(0.3)
            assert plant.proc.poll() is None, "the plant keeps running without a controller"
            states = probe.take(contract.TOPIC_PLANT_STATE)[killed_at:]
            powers = [contract.plant_state_from_message(m)[3] for m in states]
            assert len(states) > 10 and powers[-1] == 0.0, "battery power timed out to zero"
            n_commands = len(probe.take(contract.TOPIC_BATTERY_COMMAND))
            start("controller2", CONTROLLER, {"battery_limit_pu": 0.3})
            assert wait_until(lambda: len(probe.take(contract.TOPIC_BATTERY_COMMAND)) > n_commands + 25, 30.0), \
                "the restarted controller picks up the loop"
            # The killed controller stays in the ROS graph until its DDS participant's lease runs out (our
            # profiles: 5 s; Fast DDS's default, 20 s): while the restarted one is there too, the plant
            # sees two writers on battery/command, raises an alarm and trusts neither (issue 11); then it
            # pairs with the restarted one. Measured: paired 5.2 to 6.0 s after the kill (20.1 to 20.4 s
            # with the default lease), 5.1 to 5.2 s beside two busy processes; this wait starts 2 to 3 s
            # after the kill, and 15 s leaves a margin for load. The killed one may have left before the
            # new one is up (then no alarm).
            before = int(plant_diagnostics(probe).get("commands", 0))
            assert wait_until(lambda: int(plant_diagnostics(probe).get("commands", 0)) > before + 25, 15.0)
            # Authenticated, the new controller's commands count at once; the plant pairs with it once the killed
            # one has left the graph.
            assert wait_until(lambda: int(plant_diagnostics(probe).get("re_pairings", 0)) == 1, 15.0)
        finally:
            probe.close()


def test_a_stalled_realtime_plant_stays_on_its_reporting_grid_and_counts_what_it_skipped(tmp_path):
    """Realtime measurements are stamped with exact reporting instants t0 + k T, T the timer's period in ns.

    60 frames/s, a period that is not a whole number of ns (rclpy's timer runs
    at int(1e9 / 60) ns). The plant is stopped (SIGSTOP) for 0.3 s, about 18
    periods: afterwards it reports the latest instant, still on the grid, and
    its diagnostics count the instants it skipped, as many as the gaps in the
    stamps show.
    """
    rate = 60.0
    period_ns = int((1.0 / rate) * 1e9)
    domain = fresh_domain_id()
    with node_processes(tmp_path, domain) as start:
        probe = Probe(domain, (contract.TOPIC_PMU, contract.TOPIC_PLANT_STATE, contract.TOPIC_DIAGNOSTICS))
        try:
            start("controller", CONTROLLER, {"battery_limit_pu": 0.3, "sample_rate_hz": rate})
            plant = start("plant", PLANT, {"mode": "realtime", "pmu_rate_hz": rate, "wait_for_subscribers": 2})
            assert wait_until(lambda: len(probe.take(contract.TOPIC_PMU)) > 30, 30.0)
            plant.proc.send_signal(signal.SIGSTOP)
            time.sleep(0.3)
            plant.proc.send_signal(signal.SIGCONT)
            resumed_at = len(probe.take(contract.TOPIC_PMU))
            assert wait_until(lambda: len(probe.take(contract.TOPIC_PMU)) > resumed_at + 60, 30.0)
            assert plant.interrupt() == 0
            time.sleep(0.3)
            skipped = int(plant_diagnostics(probe)["skipped_reports"])
        finally:
            probe.close()
    stamps = np.array([contract.ns_from_time(m.header.stamp) for m in probe.take(contract.TOPIC_PMU)])
    gaps = np.diff(stamps)
    assert np.all(gaps > 0)
    assert np.all(gaps % period_ns == 0), "every measurement on the grid t0 + k T"
    periods = gaps // period_ns
    assert periods.max() >= 10, "the stall skipped instants"
    assert skipped == int(np.sum(periods - 1)), "diagnostics count every skipped instant"
    state_stamps = {contract.ns_from_time(m.header.stamp) for m in probe.take(contract.TOPIC_PLANT_STATE)}
    assert set(stamps.tolist()) <= state_stamps, "each measurement's instant has its true state"


def test_a_realtime_run_stalled_across_its_end_still_ends_at_duration(tmp_path):
    """The tick that finds the run over, however late, reports the last instant N T and nothing after it."""
    rate, duration = 50.0, 1.0
    domain = fresh_domain_id()
    with node_processes(tmp_path, domain) as start:
        probe = Probe(domain, (contract.TOPIC_PMU, contract.TOPIC_PLANT_STATE))
        try:
            start("controller", CONTROLLER, {"battery_limit_pu": 0.3})
            plant = start("plant", PLANT, {"mode": "realtime", "pmu_rate_hz": rate, "duration_s": duration,
                                           "wait_for_subscribers": 2})
            assert wait_until(lambda: len(probe.take(contract.TOPIC_PLANT_STATE)) > 0, 30.0)
            time.sleep(0.7)
            plant.proc.send_signal(signal.SIGSTOP)
            time.sleep(0.6)  # across the run's end at 1.0 s
            plant.proc.send_signal(signal.SIGCONT)
            assert plant.wait(timeout=30.0) == 0
            time.sleep(0.3)
        finally:
            probe.close()
    states = [contract.ns_from_time(m.header.stamp) for m in probe.take(contract.TOPIC_PLANT_STATE)]
    measurements = [contract.ns_from_time(m.header.stamp) for m in probe.take(contract.TOPIC_PMU)]
    assert states[-1] - states[0] == round(duration * 1e9), "the final state is at t0 + duration"
    assert max(measurements) < states[-1], "no measurement at or after the end"


def test_killed_plant_leaves_the_controller_idle_and_alive(tmp_path):
    domain = fresh_domain_id()
    with node_processes(tmp_path, domain) as start:
        probe = Probe(domain, (contract.TOPIC_DIAGNOSTICS, contract.TOPIC_BATTERY_COMMAND))
        try:
            controller = start("controller", CONTROLLER, {"battery_limit_pu": 0.3})
            plant = start("plant", PLANT, {"mode": "realtime", "wait_for_subscribers": 1})
            assert wait_until(lambda: len(probe.take(contract.TOPIC_BATTERY_COMMAND)) > 25, 30.0)
            plant.kill()

            def stale():
                return any(contract.diagnostic_values(m, "controller") is not None and m.status[0].message == "STALE"
                           for m in probe.take(contract.TOPIC_DIAGNOSTICS)[-3:])

            assert wait_until(stale, 5.0), "controller reports STALE"
            time.sleep(1.0)
            assert controller.proc.poll() is None, "the controller is idle, not crashed"
            assert controller.interrupt() == 0
            assert "Traceback" not in controller.output()
        finally:
            probe.close()


def test_lockstep_plant_never_hangs_on_a_silent_controller(tmp_path):
    """A command publisher that never answers: each sample times out, zero power, counted."""
    domain = fresh_domain_id()
    with node_processes(tmp_path, domain) as start:
        probe = Probe(domain, (contract.TOPIC_PMU, contract.TOPIC_PLANT_STATE, contract.TOPIC_DIAGNOSTICS))
        try:
            assert probe.wait_matched(contract.TOPIC_BATTERY_COMMAND, 0, 1.0)  # a silent command publisher
            plant = start("plant", PLANT, {"mode": "lockstep", "duration_s": 0.5, "wait_for_subscribers": 1,
                                           "lockstep_timeout_s": 0.05})
            assert plant.wait(timeout=60) == 0
            time.sleep(0.3)
            diag = plant_diagnostics(probe)
        finally:
            probe.close()
    assert int(diag["deadline_misses"]) == 25 and int(diag["samples"]) == 25
    powers = [contract.plant_state_from_message(m)[3] for m in probe.take(contract.TOPIC_PLANT_STATE)]
    assert len(powers) == 26 and set(powers) == {0.0}


def test_a_plant_waiting_for_nobody_says_so_and_gives_up(tmp_path):
    """Issue 10 section 7: what it waits for (topic, how many, how many it has), then a bounded wait."""
    with node_processes(tmp_path, fresh_domain_id()) as start:
        plant = start("plant", PLANT, {"wait_for_subscribers": 2, "wait_timeout_s": 5.5})
        assert plant.wait(timeout=60) == 1
        output = plant.output()
    lines = [line for line in output.splitlines() if "[plant]" in line]
    waiting = "waiting for 2 subscriber(s) on /pmu (has 0) and a controller publishing on /battery/command (has none)"
    assert lines[0].startswith("[INFO]") and waiting in lines[0]
    assert any(line.startswith("[WARN]") and waiting in line for line in lines[1:]), "said again while waiting"
    assert lines[-1].startswith("[ERROR]") and "gave up after 5." in lines[-1] and waiting in lines[-1]
    assert "Traceback" not in output


def test_logger_survives_publishers_that_come_and_go(tmp_path):
    from nni_msgs_adapter.recording.mcap_io import read_messages

    domain = fresh_domain_id()
    recording = tmp_path / "comings_and_goings.mcap"
    with node_processes(tmp_path, domain) as start:
        logger = start("logger", LOGGER, {"output_path": str(recording), "discovery_period_s": 0.1})
        start("controller", CONTROLLER, {"battery_limit_pu": 0.3})
        first = start("plant1", PLANT, {"mode": "lockstep", "duration_s": 1.0, "wait_for_subscribers": 2})
        assert first.wait(timeout=60) == 0
        second = start("plant2", PLANT, {"mode": "lockstep", "duration_s": 1.0, "wait_for_subscribers": 2})
        assert second.wait(timeout=60) == 0
        time.sleep(0.5)
        assert logger.proc.poll() is None
        assert logger.interrupt() == 0
    states = [r for r in read_messages(recording) if r.topic == "/" + contract.TOPIC_PLANT_STATE]
    assert len(states) == 2 * 51, "both plants' runs recorded: 1 s at 50 frames/s each, t_0 .. t_50"


def test_invalid_params_file_is_rejected_with_its_reason(tmp_path):
    params = tmp_path / "bad.yaml"
    params.write_text("/**/controller:\n  ros__parameters:\n    gain_k: 1.2\n    gain_l: 1.1\n")
    with node_processes(tmp_path, fresh_domain_id()) as start:
        node = start("controller", CONTROLLER, ros_args=("--params-file", str(params)))
        assert node.wait(timeout=30) != 0
        output = node.output()
    assert "K must be less than L" in output and "Traceback" not in output


# --- soak (opt-in) -------------------------------------------------------------------------


@pytest.mark.soak
def test_soak_zero_loss_on_reliable_topics(tmp_path):
    """Minutes of realtime loop at 100 frames/s: every sample reaches controller, logger and a subscriber."""
    from nni_msgs_adapter.recording.mcap_io import read_messages

    minutes = 3.0
    domain = fresh_domain_id()
    recording = tmp_path / "soak.mcap"
    with node_processes(tmp_path, domain) as start:
        probe = Probe(domain, (contract.TOPIC_PMU, contract.TOPIC_BATTERY_COMMAND, contract.TOPIC_DIAGNOSTICS))
        try:
            logger = start("logger", LOGGER, {"output_path": str(recording), "discovery_period_s": 0.1})
            start("controller", CONTROLLER, {"battery_limit_pu": 0.3, "sample_rate_hz": 100.0})
            plant = start("plant", PLANT, {"mode": "realtime", "pmu_rate_hz": 100.0, "duration_s": minutes * 60,
                                           "wait_for_subscribers": 3})
            assert plant.wait(timeout=minutes * 60 + 60) == 0
            time.sleep(1.0)
            diag = plant_diagnostics(probe)
            assert logger.interrupt() == 0
            sent = int(diag["measurements"])
            received = probe.take(contract.TOPIC_PMU)
        finally:
            probe.close()
    logged = {}
    for record in read_messages(recording):
        logged[record.topic] = logged.get(record.topic, 0) + 1
    assert len(received) == sent, "the probe received every measurement"
    assert logged["/pmu"] == sent, "the logger recorded every measurement"
    assert int(diag["commands"]) == sent and logged["/battery/command"] >= sent
    stamps = np.array([contract.ns_from_time(m.header.stamp) for m in received])
    assert np.all(np.diff(stamps) > 0)
