"""The plant's reporting loop and command path (nni_plant_sim.reporting): clock-free, no ROS.

Times are integers handed in by the test; the "physics" is a recording
integrator (state = the list of (t0, t1, powers) intervals it was asked to
integrate), so every assertion is about what the loop decided, not about RK4.
"""

from __future__ import annotations

import math

import pytest

from nni_plant_sim.reporting import (MAX_PLAUSIBLE_POWER_PU, CommandChannel, LockstepStepper, PmuSensor,
                                     RealtimeReporter, SubscriberWait, Verdict)

MS = 1_000_000
CONTROLLER, ROGUE = b"controller-gid", b"rogue-gid"


def integrate(t0_s, t1_s, state, powers):
    """A state that is the history of the integration requests."""
    return [*state, (round(t0_s, 9), round(t1_s, 9), tuple(powers))]


def paired_channel(rating_pu=1.0, deadline_ns=100 * MS) -> CommandChannel:
    channel = CommandChannel(rating_pu, deadline_ns)
    channel.writers({CONTROLLER: "/controller"})
    return channel


def realtime(duration_s=0.0, channels=None, t0_ns=1_000 * MS, period_ns=20 * MS, timeout_s=0.1):
    return RealtimeReporter(integrate, [], channels or [paired_channel()], duration_s, t0_ns, period_ns, timeout_s)


# --- the command path ----------------------------------------------------------------------


def test_only_answers_to_sent_unanswered_measurements_within_their_deadline_are_applied():
    channel = paired_channel()
    channel.stats.sent(1_000 * MS, 1_000 * MS)
    channel.stats.sent(1_020 * MS, 1_020 * MS)
    assert channel.admit(5_000 * MS, 0.5, 1_021 * MS) == (Verdict.UNSOLICITED, None), "a stamp never sent"
    assert channel.admit(1_020 * MS, 0.2, 1_021 * MS) == (Verdict.APPLIED, 0.2)
    assert channel.admit(1_020 * MS, 0.2, 1_022 * MS) == (Verdict.UNSOLICITED, None), "already answered"
    assert channel.admit(1_000 * MS, 0.2, 1_022 * MS)[0] is Verdict.UNSOLICITED, "older than the answered one"
    channel.stats.sent(1_040 * MS, 1_040 * MS)
    assert channel.admit(1_040 * MS, 0.1, 1_141 * MS) == (Verdict.EXPIRED, None), "101 ms after its instant"
    assert {k: channel.counts[k] for k in ("unsolicited_commands", "expired_commands")} == {
        "unsolicited_commands": 3, "expired_commands": 1}
    assert channel.stats.duplicates == 2, "of the unsolicited, those to answered or superseded measurements"


@pytest.mark.parametrize("power, verdict, applied", [
    (math.nan, Verdict.INVALID, None), (math.inf, Verdict.INVALID, None), (-math.inf, Verdict.INVALID, None),
    (1e308, Verdict.INVALID, None), (MAX_PLAUSIBLE_POWER_PU * 1.01, Verdict.INVALID, None),
    (5.0, Verdict.APPLIED, 1.0), (-5.0, Verdict.APPLIED, -1.0), (0.7, Verdict.APPLIED, 0.7),
])
def test_the_battery_never_exceeds_its_rating(power, verdict, applied):
    channel = paired_channel(rating_pu=1.0)
    channel.stats.sent(10 * MS, 10 * MS)
    assert channel.admit(10 * MS, power, 11 * MS) == (verdict, applied)
    assert channel.counts["clipped_commands"] == (1 if abs(power) == 5.0 else 0)
    assert channel.counts["invalid_commands"] == (1 if verdict is Verdict.INVALID else 0)


def test_a_second_writer_blocks_every_command_and_raises_one_alarm_per_writer():
    channel = paired_channel()
    paired = f"paired with the controller /controller ({CONTROLLER.hex()}) on battery/command"
    assert channel.take_events() == [(False, paired)]
    channel.stats.sent(10 * MS, 10 * MS)
    channel.writers({CONTROLLER: "/controller", ROGUE: "/rogue"})
    channel.writers({CONTROLLER: "/controller", ROGUE: "/rogue"})  # seen again: no new alarm
    events = channel.take_events()
    assert len(events) == 1 and events[0][0] and "/rogue" in events[0][1]
    assert channel.admit(10 * MS, 0.1, 11 * MS) == (Verdict.FOREIGN, None), "nobody can be told apart: nothing applied"
    assert channel.counts["writer_alarms"] == 1 and channel.counts["foreign_commands"] == 1 and channel.compromised
    assert "foreign command dropped" in channel.take_events()[0][1]
    channel.writers({CONTROLLER: "/controller"})  # the rogue left
    assert channel.admit(10 * MS, 0.1, 12 * MS) == (Verdict.APPLIED, 0.1)


def test_a_restarted_controller_is_paired_once_the_old_one_left_the_graph():
    channel = paired_channel()
    channel.writers({CONTROLLER: "/controller", b"new": "/controller"})  # the dead one is still in the graph
    channel.writers({b"new": "/controller"})
    assert channel.paired == (b"new", "/controller") and channel.counts["re_pairings"] == 1
    assert not channel.foreign


def test_no_writer_at_the_start_means_nothing_is_trusted_until_one_is_paired():
    channel = CommandChannel(1.0, 100 * MS)
    channel.stats.sent(10 * MS, 10 * MS)
    assert channel.admit(10 * MS, 0.1, 11 * MS)[0] is Verdict.FOREIGN
    channel.writers({CONTROLLER: "/controller", ROGUE: "/rogue"})
    assert channel.paired is None and channel.counts["writer_alarms"] == 2, "two at once: neither is trusted"


def test_the_paired_controllers_zero_on_stale_data_is_a_stand_down():
    channel = paired_channel()
    channel.stats.sent(10 * MS, 10 * MS)
    assert channel.admit(10 * MS, 0.3, 11 * MS) == (Verdict.APPLIED, 0.3)
    assert channel.admit(200 * MS, 0.0, 250 * MS) == (Verdict.STAND_DOWN, 0.0), "realtime: zero from now"
    assert channel.admit(200 * MS, 0.0, 250 * MS, awaited_ns=220 * MS) == (Verdict.STAND_DOWN, None), \
        "lockstep: the sample waits for its own answer"
    assert not channel.compromised and channel.counts["stand_down_commands"] == 2


# --- realtime ----------------------------------------------------------------------------


def test_realtime_reports_on_its_grid_and_counts_skipped_instants():
    loop = realtime()
    first = loop.start(1_000 * MS + 300_000)
    assert first.measurement.stamp_ns == 1_000 * MS and first.states == (first.measurement,)
    assert loop.on_timer(1_010 * MS) is None, "between instants: nothing"
    late = loop.on_timer(1_095 * MS)  # instants 1, 2, 3 passed; 4 is the latest
    assert late.measurement.stamp_ns == 1_080 * MS and loop.sample == 5
    assert loop.channels[0].stats.skipped_reports == 3
    assert late.measurement.state[-1] == (0.0, 0.08, (0.0,)), "integrated to the instant reported"


def test_a_command_acts_from_its_arrival_and_the_loop_integrates_ahead_then_redoes():
    loop = realtime()
    loop.start(1_000 * MS)
    verdict, output = loop.command(0, 1_000 * MS, 0.25, 1_005 * MS)
    assert verdict is Verdict.APPLIED and output is None
    assert loop.state[-2:] == [(0.0, 0.005, (0.0,)), (0.005, 0.02, (0.25,))], "to the arrival, then ahead to t_1"
    report = loop.on_timer(1_020 * MS + 100_000).measurement
    assert report.stamp_ns == 1_020 * MS and report.powers == (0.25,) and report.t_s == pytest.approx(0.02)
    loop.command(0, 1_020 * MS, -0.1, 1_024 * MS)
    loop.command(0, 1_020 * MS, 0.9, 1_026 * MS)  # already answered: dropped, the ahead state stands
    assert loop.state[-2:] == [(0.02, 0.024, (0.25,)), (0.024, 0.04, (-0.1,))]
    assert loop.channels[0].counts["unsolicited_commands"] == 1


def test_with_several_generators_the_loop_integrates_ahead_once_every_one_has_answered():
    calls = []

    def counting(t0_s, t1_s, state, powers):
        calls.append((round(t0_s, 9), round(t1_s, 9)))
        return integrate(t0_s, t1_s, state, powers)

    loop = RealtimeReporter(counting, [], [paired_channel() for _ in range(3)], 0.0, 1_000 * MS, 20 * MS, 0.1)
    loop.start(1_000 * MS)
    for index, (power, arrival_ms) in enumerate(((0.1, 1_003), (0.2, 1_005), (0.3, 1_007))):
        loop.command(index, 1_000 * MS, power, arrival_ms * MS)
    assert calls == [(0.0, 0.003), (0.003, 0.005), (0.005, 0.007), (0.007, 0.02)], "each piece once, no redo"
    report = loop.on_timer(1_020 * MS).measurement
    assert report.state[-4:] == [(0.0, 0.003, (0.0, 0.0, 0.0)), (0.003, 0.005, (0.1, 0.0, 0.0)),
                                 (0.005, 0.007, (0.1, 0.2, 0.0)), (0.007, 0.02, (0.1, 0.2, 0.3))], \
        "each command in force from its arrival"
    assert len(calls) == 4, "the tick found the instant integrated already"


def test_a_command_finding_an_instant_unreported_reports_it_first_with_the_power_then_in_force():
    loop = realtime()
    loop.start(1_000 * MS)
    loop.command(0, 1_000 * MS, 0.2, 1_003 * MS)
    verdict, output = loop.command(0, 1_000 * MS, 0.3, 1_021 * MS)  # the tick for t_1 is late
    assert output.measurement.stamp_ns == 1_020 * MS and output.measurement.powers == (0.2,)
    assert verdict is Verdict.UNSOLICITED


def test_the_power_in_force_decays_to_zero_after_the_command_timeout():
    loop = realtime(timeout_s=0.05)
    loop.start(1_000 * MS)
    loop.command(0, 1_000 * MS, 0.2, 1_001 * MS)
    loop.on_timer(1_020 * MS)
    assert loop.channels[0].power_pu == 0.2
    loop.on_timer(1_060 * MS)
    assert loop.channels[0].power_pu == 0.0 and loop.channels[0].stats.command_timeouts == 1


def test_a_realtime_run_ends_at_its_last_instant_with_a_state_and_no_measurement():
    loop = realtime(duration_s=0.1)
    loop.start(1_000 * MS)
    end = loop.on_timer(1_500 * MS)  # stalled across the end
    assert end.measurement is None and end.done and end.states[0].stamp_ns == 1_100 * MS
    assert loop.on_timer(1_600 * MS) is None and loop.command(0, 1_100 * MS, 0.1, 1_601 * MS) == (None, None)


# --- lockstep ----------------------------------------------------------------------------


def lockstep(duration_s=0.06, channels=None):
    return LockstepStepper(integrate, [], channels or [paired_channel()], duration_s, 0.02, 1.0)


def test_lockstep_steps_one_period_per_answer_at_exact_sample_instants():
    loop = lockstep()
    sample = loop.start(0).measurement
    assert sample.stamp_ns == 0
    loop.sent(5 * MS)
    verdict, output = loop.command(0, 0, 0.1, 6 * MS)
    assert verdict is Verdict.APPLIED
    assert output.states[0].stamp_ns == 0 and output.states[0].powers == (0.1,), "the completed sample"
    assert output.measurement.stamp_ns == 20 * MS and loop.state[-1] == (0.0, 0.02, (0.1,))
    loop.sent(7 * MS)
    assert loop.channels[0].stats.turnaround.count == 1


def test_lockstep_times_each_turnaround_once_and_every_generator_reports_it():
    """From the last answer of a sample to the next measurement out: one value a sample, whatever N."""
    loop = lockstep(channels=[paired_channel(), paired_channel(), paired_channel()])
    loop.start(0)
    loop.sent(1 * MS)
    for index, arrival_ms in ((0, 2), (2, 3), (1, 4)):
        loop.command(index, 0, 0.1, arrival_ms * MS)
    loop.sent(4 * MS + 250_000)
    summaries = [channel.summary() for channel in loop.channels]
    assert loop.turnaround.count == 1
    assert [s["turnaround_max_ms"] for s in summaries] == [0.25] * 3, "from the last answer (4 ms), not the first"
    assert [s["latency_max_ms"] for s in summaries] == [1.0, 3.0, 2.0], "latency stays each generator's own"


def test_lockstep_drops_answers_to_other_samples_and_times_out_to_zero():
    loop = lockstep()
    loop.start(0)
    loop.sent(0)
    assert loop.command(0, 20 * MS, 0.1, 1 * MS) == (Verdict.UNSOLICITED, None), "answering /clock ahead"
    assert loop.on_timer(500 * MS) is None
    output = loop.on_timer(1_001 * MS)
    assert output.states[0].powers == (0.0,) and loop.channels[0].stats.deadline_misses == 1
    loop.sent(1_002 * MS)
    assert loop.command(0, 0, 0.1, 1_003 * MS)[0] is Verdict.EXPIRED, "the sample completed without it"


def test_lockstep_waits_for_every_generator_of_the_plant():
    channels = [paired_channel(), paired_channel()]
    loop = lockstep(channels=channels)
    loop.start(0)
    loop.sent(0)
    assert loop.command(1, 0, 0.2, 1 * MS) == (Verdict.APPLIED, None), "one of two answers: no step yet"
    verdict, output = loop.command(0, 0, -0.1, 2 * MS)
    assert output.states[0].powers == (-0.1, 0.2) and loop.state[-1] == (0.0, 0.02, (-0.1, 0.2))


def test_lockstep_run_ends_with_the_completed_and_the_final_state():
    loop = lockstep(duration_s=0.04)
    loop.start(0)
    for k in range(2):
        loop.sent(k)
        verdict, output = loop.command(0, k * 20 * MS, 0.0, k + 1)
    assert output.done and output.measurement is None
    assert [state.stamp_ns for state in output.states] == [20 * MS, 40 * MS]


# --- start and sensor ----------------------------------------------------------------------


def test_the_wait_for_subscribers_says_what_it_waits_for_and_gives_up():
    wait = SubscriberWait(2, 0.2, 10.0, since_ns=0, log_period_s=5.0)
    assert wait.poll(0, 1, 0, "/pmu", "/battery/command") == (
        "wait", "info", "waiting for 2 subscriber(s) on /pmu (has 1) and a controller publishing on "
                        "/battery/command (has none) (waited 0.0 s of 10)")
    assert wait.poll(1 * 10**9, 1, 0, "/pmu", "/battery/command") == ("wait", None, None), "said already"
    assert wait.poll(6 * 10**9, 1, 0, "/pmu", "/battery/command")[1] == "warning"
    assert wait.poll(7 * 10**9, 2, 1, "/pmu", "/battery/command") == ("wait", None, None), "settling"
    assert wait.poll(7 * 10**9 + 2 * 10**8, 2, 1, "/pmu", "/battery/command")[0] == "start"
    gave_up = SubscriberWait(1, 0.0, 10.0, since_ns=0).poll(11 * 10**9, 0, 0, "/pmu", "/battery/command")
    assert gave_up[:2] == ("give_up", "error") and gave_up[2].startswith("gave up after 11.0 s waiting for")


def test_the_pmu_quantises_after_its_noise():
    assert PmuSensor(0.0, 0.0, 0.01, 0).read(0.123456, 2.0) == (pytest.approx(0.12), 2.0)
    noisy = [PmuSensor(0.1, 0.0, 0.0, seed).read(0.0, 0.0)[0] for seed in (1, 2)]
    assert noisy[0] != noisy[1] and PmuSensor(0.1, 0.0, 0.0, 1).read(0.0, 0.0)[0] == noisy[0], "seeded"


def test_an_unlisted_writer_blocks_but_is_never_paired_and_a_named_one_keeps_its_pairing():
    channel = CommandChannel(1.0, 100 * MS)
    channel.writers({}, unlisted=1)  # matched, not yet in the graph: maybe the controller, maybe not
    assert channel.paired is None and channel.foreign
    channel.writers({CONTROLLER: "(unnamed)"})
    assert channel.paired == (CONTROLLER, "(unnamed)") and not channel.foreign
    channel.writers({CONTROLLER: "/controller"})
    assert channel.paired == (CONTROLLER, "/controller") and channel.counts["re_pairings"] == 0
