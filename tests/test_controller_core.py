"""The controller's core and configuration, clock-free, no ROS: end of run, g measured, the coi reference."""

from __future__ import annotations

import math

import pytest

from nni_battery_controller.controller_config import ControllerConfig, prepared
from nni_battery_controller.controller_core import MAX_PENDING_STAMPS, ControllerCore
from nni_msgs_adapter.ros.defaults import controller_defaults

MS = 1_000_000
NOW = 1_700_000_000_000 * MS


def core_after_one_measurement() -> ControllerCore:
    core = ControllerCore(ControllerConfig(controller_defaults()))  # 50/s, stale after 5 periods: 100 ms
    assert core.measurement(NOW, 0.9, 0.0, NOW, NOW) is not None
    return core


def test_the_silence_after_the_plants_end_of_run_is_no_stale_episode():
    core = core_after_one_measurement()
    assert core.end_of_run() is True and core.end_of_run() is False, "news once"
    assert core.silence(NOW + 500 * MS) is None and not core.gate.stale
    assert core.gate.counts["stale_episodes"] == 0


def test_in_lockstep_wall_clock_silence_is_no_stale_episode_until_the_plants_clock_is_gone():
    """A lockstep plant that is slow (a loaded machine) holds simulated time still: no stand-down."""
    core = core_after_one_measurement()
    assert core.silence(NOW + 500 * MS, lockstep_clock=True) is None and not core.gate.stale
    assert core.silence(NOW + 600 * MS, lockstep_clock=False) == NOW + 600 * MS and core.gate.stale


def test_a_measurement_after_the_end_notice_cancels_it():
    """A false or early notice spares the stand-down only for the silence right after it."""
    core = core_after_one_measurement()
    core.end_of_run()
    assert core.measurement(NOW + 20 * MS, 0.9, 0.0, NOW + 20 * MS, NOW + 20 * MS) is not None
    assert core.silence(NOW + 200 * MS) == NOW + 200 * MS and core.gate.stale


def test_an_end_notice_after_the_watchdog_fired_or_before_any_run_is_no_news():
    core = core_after_one_measurement()
    assert core.silence(NOW + 150 * MS) is not None
    assert core.end_of_run() is False
    idle = ControllerCore(ControllerConfig(controller_defaults()))
    assert idle.end_of_run() is False


# --- restoring_power measured needs no SMIB model (issue 14: IEEE 39's G10 carries P_M = 1.0 pu) -----------------

def measured_values(**changes) -> dict:
    return {**controller_defaults(), "restoring_power": "measured", "reference_angle_rad": 0.3, **changes}


def test_g_measured_takes_a_generator_at_its_rating_without_a_model_of_p_max():
    """P_M = P_max = 1.0 pu is no SMIB with an equilibrium, but g measured uses neither P_max nor delta_bar."""
    core = ControllerCore(ControllerConfig(measured_values(p_mech_pu=1.0, p_max_pu=1.0)))
    answer = core.measurement(NOW, 0.3, 0.0, NOW, NOW, 1.05)
    assert answer.power_pu == pytest.approx(1.05 - 1.0, abs=1e-15)  # w = x3 - L*0 - (P_M - P_E)
    assert core.config.plant is None and math.isnan(answer.w_hat)
    with pytest.raises(ValueError, match="P_M must be less than P_max"):
        ControllerConfig({**controller_defaults(), "p_mech_pu": 1.0, "p_max_pu": 1.0})  # the model does need it


@pytest.mark.parametrize("changes, reason", [
    ({"gain_k": 1.2}, "K must be less than L"),
    ({"reference_angle_rad": math.inf}, "measured needs reference_angle_rad"),
    ({"battery_limit_pu": -0.1}, "battery"),
])
def test_g_measured_still_refuses_what_is_really_invalid(changes, reason):
    with pytest.raises(ValueError, match=reason):
        ControllerConfig(measured_values(p_mech_pu=1.0, **changes))


# --- reference coi: the centre of inertia of the listed generators, one stamp at a time --------------------------

COI = {"reference": "coi", "coi_namespaces": ["/gen1", "/gen2", "/gen3"], "coi_inertias": [2.0, 1.0, 1.0]}
ONE_WRITER = 1


def coi_core(**changes) -> ControllerCore:
    """The controller of /gen2 (index 1) among three generators, weights 1/2, 1/4, 1/4."""
    return ControllerCore(ControllerConfig(measured_values(p_mech_pu=0.7, **COI, **changes), "/gen2"))


def send(core, index, stamp_ns, delta, writers=ONE_WRITER, p_elec=0.7):
    return core.receive(index, (stamp_ns, delta, 0.0), [p_elec], writers, stamp_ns, stamp_ns, lambda: 1)


def test_a_coi_sample_is_answered_once_every_generator_reported_its_stamp_in_any_order():
    core = coi_core()
    assert send(core, 1, NOW, 0.9) is None and send(core, 0, NOW, 0.2) is None
    answer = send(core, 2, NOW, 0.6)
    assert answer.stamp_ns == NOW
    assert answer.angle_dev_rad == pytest.approx(0.9 - (0.5 * 0.2 + 0.25 * 0.9 + 0.25 * 0.6) - 0.3, abs=1e-15)
    assert core.gate.counts["samples"] == 1 and not core.coi.pending


def test_a_missing_neighbour_leaves_the_stamp_unanswered_counted_and_the_watchdog_stands_down():
    """gen3 falls silent: no answer on a partial centre of inertia; after stale_after (100 ms) zero power, STALE."""
    core = coi_core()
    for index in range(3):
        send(core, index, NOW, 0.5)
    assert core.gate.counts["samples"] == 1
    answers = [send(core, index, NOW + k * 20 * MS, 0.5) for k in range(1, 8) for index in (0, 1)]
    assert answers == [None] * len(answers)
    assert core.coi.counts["coi_incomplete"] == 7 - MAX_PENDING_STAMPS and len(core.coi.pending) == MAX_PENDING_STAMPS
    assert core.status()[:2] == ("WARN", "centre of inertia: coi_incomplete")
    assert core.silence(NOW + 150 * MS) == NOW + 150 * MS and core.gate.stale  # the zero command's stamp
    assert core.status()[0] == "STALE"


def test_a_later_complete_stamp_gives_up_the_earlier_incomplete_ones():
    core = coi_core()
    send(core, 1, NOW, 0.5)
    send(core, 0, NOW, 0.5)  # gen3's sample of NOW never comes
    for index in range(3):
        answer = send(core, index, NOW + 20 * MS, 0.5)
    assert answer.stamp_ns == NOW + 20 * MS and core.coi.counts["coi_incomplete"] == 1 and not core.coi.pending
    assert core.status()[0] == "WARN" and core.status()[0] == "OK", "WARN while the counter grows"


def test_a_neighbours_bad_message_or_a_second_writer_on_a_listed_topic_is_counted_and_never_used():
    core = coi_core()
    assert core.receive(0, None, [], ONE_WRITER, NOW, NOW, lambda: 1) is None  # malformed neighbour
    assert send(core, 2, NOW, math.nan) is None and send(core, 2, NOW, 1e7) is None  # non-finite, implausible
    assert send(core, 0, NOW, 0.5, writers=2) is None  # a rogue beside the plant on /gen1/pmu
    assert send(core, 1, NOW, 0.5) is None and send(core, 0, NOW, 0.5) is None  # gen3 still missing
    assert send(core, 0, NOW, 0.9) is None  # gen1 again for the stamp: its first sample stands
    assert core.coi.counts == {"coi_incomplete": 0, "coi_rejected": 4, "coi_untrusted": 1}
    assert core.gate.counts["malformed"] == 0 and core.gate.counts["samples"] == 0
    assert send(core, 2, NOW, 0.5).angle_dev_rad == pytest.approx(0.5 - 0.5 - 0.3, abs=1e-15)  # gen1's 0.5 stood


def test_the_own_measurement_still_goes_through_the_gate():
    """A duplicate stamp, once complete again, is the gate's duplicate; an own malformed message is malformed."""
    core = coi_core()
    for _ in range(2):
        answers = [send(core, index, NOW, 0.5) for index in range(3)]
    assert answers[-1] is None and core.gate.counts["duplicate"] == 1 and core.gate.counts["samples"] == 1
    assert core.receive(1, None, [], ONE_WRITER, NOW, NOW, lambda: 1) is None
    assert core.receive(1, (NOW + 1, 0.5, 0.0), [], ONE_WRITER, NOW, NOW, lambda: 1) is None  # no P_E
    assert core.gate.counts["malformed"] == 2


@pytest.mark.parametrize("changes, reason", [
    ({"restoring_power": "model", "reference_angle_rad": math.inf}, "reference coi needs restoring_power measured"),
    ({"coi_inertias": [1.0, 1.0]}, "one coi_inertias value each, got 3 and 2"),
    ({"coi_namespaces": ["/gen2"], "coi_inertias": [1.0]}, "at least two generators"),
    ({"coi_namespaces": ["/gen1", "gen2", "/gen3"]}, "distinct absolute namespaces"),
    ({"coi_namespaces": ["/gen1", "/gen2/", "/gen3"]}, "distinct absolute namespaces"),
    ({"coi_namespaces": ["/gen1", "/gen2", "/gen2"]}, "distinct absolute namespaces"),
    ({"coi_namespaces": ["/gen1", "/gen3", "/gen4"]}, "include this controller's own namespace /gen2"),
    ({"coi_inertias": [1.0, 0.0, 1.0]}, "finite and positive"),
    ({"reference": "pmu"}, "apply to reference coi only"),
])
def test_a_coi_configuration_that_cannot_work_is_refused_with_its_reason(changes, reason):
    with pytest.raises(ValueError, match=reason):
        ControllerConfig({**measured_values(**COI), **changes}, "/gen2")


def test_the_angle_reference_cannot_change_once_the_node_is_up_and_the_gains_still_can():
    """The node subscribes to the coi topics at start: a later reference change would be silently not applied."""
    old = measured_values(**COI)
    with pytest.raises(ValueError, match="reference cannot change once the node is up"):
        prepared(old, {**old, "reference": "pmu", "coi_namespaces": [], "coi_inertias": []}, "/gen2", active=False)
    with pytest.raises(ValueError, match="coi_inertias cannot change once the node is up"):
        prepared(old, {**old, "coi_inertias": [1.0, 1.0, 1.0]}, "/gen2", active=False)
    assert prepared(old, {**old, "gain_k": 0.9}, "/gen2", active=True).ctrl.gain_k == 0.9
    with pytest.raises(ValueError, match="battery_limit_pu cannot change while a run is active"):
        prepared(old, {**old, "battery_limit_pu": 0.2}, "/gen2", active=True)
