"""Loop timing bookkeeping at the plant (nni_plant_sim.loop_stats): pure, no ROS."""

from __future__ import annotations

import numpy as np
import pytest

from nni_plant_sim.loop_stats import RESOLUTION_NS, LoopStats, TimingDistribution

MS = 1_000_000


def test_histogram_percentiles_are_nearest_rank_to_its_resolution():
    rng = np.random.default_rng(7)
    values = rng.integers(0, 5 * MS, 10_001)
    distribution = TimingDistribution(0, 100 * MS)
    for value in values:
        distribution.add(int(value))
    ordered = np.sort(values)
    for percent in (1, 50, 99, 100):
        exact = ordered[max(1, int(np.ceil(percent / 100 * values.size))) - 1]
        assert abs(distribution.percentiles_ns((percent,))[0] - exact) <= RESOLUTION_NS / 2
    outside = TimingDistribution(0, MS)
    for value in (-5, 2 * MS, 3 * MS):
        outside.add(value)
    assert outside.percentiles_ns((1, 50, 100)) == [-5.0, 2.0 * MS, 3.0 * MS], "values outside the bins kept exactly"
    with pytest.raises(ValueError):
        TimingDistribution(0, MS).percentiles_ns((50,))


def test_answers_order_and_count_only_answers_to_sent_measurements():
    """The controller's zero on stale data answers no measurement: applied, but it must not refuse the next answer."""
    stats = LoopStats()
    stats.sent(1_000 * MS, 1_000 * MS)
    assert stats.answered(1_000 * MS, 1_001 * MS)
    stats.sent(1_020 * MS, 1_020 * MS)
    stale_zero_stamp = 1_025 * MS  # last stamp seen by the controller + the silence it noticed
    assert stats.answered(stale_zero_stamp, 1_026 * MS), "a command that answers nothing is still applied"
    assert stats.answered(1_020 * MS, 1_027 * MS), "the real answer to the next measurement is not refused"
    assert stats.latency.count == 2 and stats.late == 0
    assert not stats.answered(1_020 * MS, 1_028 * MS) and stats.duplicates == 1


def test_jitter_is_recorded_only_when_the_timer_reported_the_instant():
    stats = LoopStats()
    stats.tick(10 * MS + 300_000, 10 * MS)
    stats.tick(30 * MS, None)  # reported first by a command that arrived after the instant
    assert stats.jitter.count == 1 and stats.jitter.percentiles_ns((100,)) == [300_500.0]
    stats.sent(10 * MS, 10 * MS)
    stats.tick(20 * MS + 100_000, 20 * MS)
    assert stats.deadline_misses == 1, "the previous measurement was unanswered at the next instant"
    assert stats.summary()["measurements"] == 1
