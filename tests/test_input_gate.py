"""The controller's input gate (nni_battery_controller.input_gate): clock-free, no ROS."""

from __future__ import annotations

import math

import pytest

from nni_battery_controller.input_gate import COUNTERS, InputGate, Verdict

MS = 1_000_000
NOW = 1_700_000_000_000 * MS  # the reference clock (wall time), ns


def gate(reanchor_after: int = 5) -> InputGate:
    return InputGate(gap_ns=100 * MS, tolerance_ns=1_000 * MS, reanchor_after=reanchor_after)


@pytest.mark.parametrize("delta, speed, verdict", [
    (math.nan, 0.0, Verdict.NON_FINITE), (0.9, math.inf, Verdict.NON_FINITE), (-math.inf, 0.0, Verdict.NON_FINITE),
    (1e7, 0.0, Verdict.IMPLAUSIBLE), (0.9, 1e5, Verdict.IMPLAUSIBLE), (1e308, 0.0, Verdict.IMPLAUSIBLE),
    (0.9, 0.0, Verdict.ACCEPTED),
])
def test_values_are_checked_once_here(delta, speed, verdict):
    g = gate()
    assert g.check(NOW, delta, speed, NOW, NOW) is verdict
    assert g.counts[verdict.value] == 1 and sum(g.counts.values()) == 1


def test_order_duplicates_and_gaps():
    g = gate()
    assert g.check(NOW, 0.9, 0.0, NOW, NOW) is Verdict.ACCEPTED
    assert g.check(NOW, 0.9, 0.0, NOW, NOW) is Verdict.DUPLICATE
    assert g.check(NOW - 5, 0.9, 0.0, NOW, NOW) is Verdict.OUT_OF_ORDER
    assert g.check(NOW + 20 * MS, 0.9, 0.0, NOW, NOW) is Verdict.ACCEPTED
    resumed = g.check(NOW + 200 * MS, 0.9, 0.0, NOW + 200 * MS, NOW + 200 * MS)
    assert resumed is Verdict.RESET and resumed.accepted and resumed.resets, "a gap of 180 ms > 100 ms"
    assert g.malformed() is Verdict.MALFORMED
    assert {k: v for k, v in g.counts.items() if v} == {
        "samples": 3, "duplicate": 1, "out_of_order": 1, "resets": 1, "malformed": 1}
    assert set(g.counts) == set(COUNTERS)


def test_one_far_future_stamp_is_rejected_and_does_not_lock_the_stream_out():
    """Attack 4 of issue 11: a rogue (or a PMU clock glitch) stamps one measurement far in the future."""
    g = gate()
    assert g.check(NOW, 0.9, 0.0, NOW, NOW).accepted
    assert g.check(NOW + 3_600_000 * MS, 0.9, 0.0, NOW + MS, NOW + MS) is Verdict.IMPLAUSIBLE_STAMP
    for k in range(1, 400):
        stamp = NOW + k * 20 * MS
        assert g.check(stamp, 0.9, 0.0, stamp, stamp) is Verdict.ACCEPTED
    assert g.counts["reanchors"] == 0 and g.counts["out_of_order"] == 0


def test_a_stream_whose_clock_jumped_is_followed_after_n_rejections_and_counted():
    g = gate(reanchor_after=5)
    assert g.check(NOW, 0.9, 0.0, NOW, NOW).accepted
    skew = 5_000 * MS  # the PMU's clock now runs 5 s ahead of ours: beyond the tolerance
    verdicts = [g.check(NOW + skew + k * 20 * MS, 0.9, 0.0, NOW + k * 20 * MS, NOW + k * 20 * MS)
                for k in range(1, 9)]
    assert verdicts[:4] == [Verdict.IMPLAUSIBLE_STAMP] * 4
    assert verdicts[4] is Verdict.REANCHORED and verdicts[4].resets
    assert verdicts[5:] == [Verdict.ACCEPTED] * 3, "followed on its own clock from then on"
    assert g.counts["reanchors"] == 1 and g.offset_ns == skew


def test_a_plausible_jump_ahead_locks_out_only_until_reanchored():
    g = gate(reanchor_after=3)
    assert g.check(NOW + 900 * MS, 0.9, 0.0, NOW, NOW).accepted  # within the tolerance, but ahead
    verdicts = [g.check(NOW + k * 20 * MS, 0.9, 0.0, NOW + k * 20 * MS, NOW + k * 20 * MS) for k in range(1, 5)]
    assert verdicts == [Verdict.OUT_OF_ORDER, Verdict.OUT_OF_ORDER, Verdict.REANCHORED, Verdict.ACCEPTED]


def test_duplicates_never_reanchor():
    g = gate(reanchor_after=2)
    g.check(NOW, 0.9, 0.0, NOW, NOW)
    assert [g.check(NOW, 0.9, 0.0, NOW, NOW) for _ in range(5)] == [Verdict.DUPLICATE] * 5


def test_the_silence_watchdog_is_due_just_past_the_gap_after_the_last_measurement():
    """The node's watchdog fires when :meth:`InputGate.silence` would first start the episode, else every gap."""
    g = gate()
    assert g.silence_check_in_ns(NOW) == 100 * MS, "nothing heard yet: check again a gap on"
    g.check(NOW, 0.9, 0.0, NOW, NOW + 3)
    due_in = g.silence_check_in_ns(NOW + 30 * MS)
    assert due_in == 70 * MS + 4
    assert g.silence(NOW + 30 * MS + due_in - 1) is None and g.silence(NOW + 30 * MS + due_in) is not None
    assert g.silence_check_in_ns(NOW + 200 * MS) == 100 * MS, "stale already: a gap on"
    fresh = gate()
    fresh.check(NOW, 0.9, 0.0, NOW, NOW)
    assert fresh.silence_check_in_ns(NOW + 500 * MS) == 100 * MS, "overdue (stood down): a gap on"


def test_silence_is_one_stale_episode_with_a_zero_stamped_after_the_last_measurement():
    g = gate()
    assert g.silence(NOW) is None, "nothing heard yet: nothing to stand down from"
    g.check(NOW, 0.9, 0.0, NOW, NOW + 3)
    assert g.silence(NOW + 50 * MS) is None
    assert g.silence(NOW + 150 * MS) == NOW + 150 * MS - 3 and g.stale
    assert g.silence(NOW + 300 * MS) is None and g.counts["stale_episodes"] == 1
    g.check(NOW + 400 * MS, 0.9, 0.0, NOW + 400 * MS, NOW + 400 * MS)
    assert not g.stale
