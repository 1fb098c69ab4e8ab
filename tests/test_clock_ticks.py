"""Which /clock ticks a recorder with the run's key files as the loop's (issue 31): ``runs.ClockTicks``.

The plant sends one tick per measurement, at its stamp, after it; /clock has no room for a seal, so a tick is the
loop's only when a sealed measurement of its stamp was recorded, once per stamp. The sequences below are what a
recorder hears: the topics' callbacks interleave in any order.
"""

from __future__ import annotations

from nni_msgs_adapter.recording.runs import ClockTicks

MS = 1_000_000


def loop_and_foreign(decided: list) -> tuple[list, list]:
    return [item for item, loop in decided if loop], [item for item, loop in decided if not loop]


def test_a_tick_after_its_measurement_is_the_loops_and_a_copy_of_it_is_foreign():
    ticks = ClockTicks()
    assert ticks.measured(20 * MS) == []
    assert ticks.tick(20 * MS, "plant") == [("plant", True)]
    assert ticks.tick(20 * MS, "copy") == [("copy", False)]  # a tick holds only its time: once per stamp


def test_a_tick_heard_before_its_measurement_waits_for_it():
    ticks = ClockTicks()
    ticks.measured(0)
    assert ticks.tick(20 * MS, "early") == []
    assert ticks.measured(20 * MS) == [("early", True)]


def test_ticks_no_sealed_measurement_can_have_are_foreign():
    ticks = ClockTicks()
    ticks.measured(20 * MS)
    # Behind the latest measurement with no measurement of its stamp: a replay or a forgery.
    assert ticks.tick(10 * MS, "behind") == [("behind", False)]
    # 100 s ahead: waits, then decided foreign once a measurement beyond it has come, or at the end.
    assert ticks.tick(100_020 * MS, "ahead") == []
    assert ticks.tick(30 * MS, "between") == []
    assert ticks.measured(40 * MS) == [("between", False)]
    assert ticks.rest() == [("ahead", False)]
    assert ticks.rest() == []


def test_a_network_s_topics_interleaving_files_each_stamp_once():
    """Four generators' pmu topics, each in order, interleaved with the plant's ticks and a rogue's copies."""
    ticks, decided = ClockTicks(), []
    for k in range(1, 4):
        stamp = 20 * MS * k
        decided += ticks.measured(stamp)          # gen1 first
        decided += ticks.tick(stamp, f"rogue {k}")  # a rogue's copy of the stamp, before the plant's
        decided += ticks.tick(stamp, f"plant {k}")
        for _ in range(3):                        # gen2..gen4
            decided += ticks.measured(stamp)
    loop, foreign = loop_and_foreign(decided + ticks.rest())
    assert loop == ["rogue 1", "rogue 2", "rogue 3"]  # the same tick as the plant's: what /clock holds is right
    assert foreign == ["plant 1", "plant 2", "plant 3"]


def test_a_flood_of_future_ticks_is_bounded_farthest_first():
    ticks = ClockTicks(memory=4)
    ticks.measured(0)
    decided = []
    for k in range(9, 0, -1):  # nine future ticks, farthest first
        decided += ticks.tick(k * MS, k)
    # Over 2 x memory waiting: all but the memory nearest are decided foreign, the farthest first.
    assert decided == [(5, False), (6, False), (7, False), (8, False), (9, False)]
    assert ticks.measured(1 * MS) == [(1, True)]
    assert ticks.measured(3 * MS) == [(2, False), (3, True)]


def test_old_stamps_are_forgotten_in_bulk_and_a_tick_of_one_is_foreign():
    ticks = ClockTicks(memory=2)
    for k in range(5):  # five stamps: over 2 x memory, the oldest two are forgotten
        ticks.measured(k * MS)
    assert ticks.tick(0, "forgotten") == [("forgotten", False)]
    assert ticks.tick(4 * MS, "kept") == [("kept", True)]


def test_in_a_realtime_run_every_tick_is_foreign():
    ticks = ClockTicks(plant_ticks=False)
    ticks.measured(20 * MS)
    assert ticks.tick(20 * MS, "copy") == [("copy", False)]
