"""The communication link model (nni_plant_sim.link) and its use by the reporting core and the offline loop.

Pure: no ROS. The reporting core is driven with the recording integrator of
test_reporting (the state is the list of integration requests), so that the
assertions are about the pieces the loop integrates and the powers over them.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from nni_battery_controller.law import ControllerParams, SampledController
from nni_battery_controller.margins import delay_margins
from nni_battery_controller.simulate import simulate_sampled
from nni_plant_sim.integrators import advance
from nni_plant_sim.link import NO_LINK, DelayLine, Link
from nni_plant_sim.model import SmibParams
from nni_plant_sim.reporting import CommandChannel, LockstepStepper, RealtimeReporter, Verdict
from nni_plant_sim.scenarios import InitialAngle

MS = 1_000_000


def integrate(t0_s, t1_s, state, powers):
    return [*state, (round(t0_s, 9), round(t1_s, 9), tuple(powers))]


def paired_channel() -> CommandChannel:
    channel = CommandChannel(1.0, 100 * MS)
    channel.writers({b"controller-gid": "/controller"})
    return channel


# --- the model ---------------------------------------------------------------------------


def test_draws_depend_only_on_seed_generator_and_sample():
    link = Link(0.05, 0.02, 0.1, seed=7)
    forward = [[link.draw(g, k) for k in range(200)] for g in range(3)]
    backward = [[Link(0.05, 0.02, 0.1, seed=7).draw(g, k) for k in reversed(range(200))][::-1] for g in range(3)]
    assert forward == backward, "another instance, another order: the same values"
    assert forward[0] != forward[1], "generators draw independently"
    assert forward[0] != [Link(0.05, 0.02, 0.1, seed=8).draw(0, k) for k in range(200)], "the seed matters"


def test_jitter_stays_within_delay_and_delay_plus_jitter_and_spreads_over_it():
    link = Link(0.05, 0.02, seed=3)
    delays = np.array([link.draw(0, k) for k in range(2000)])
    assert delays.min() >= 0.05 and delays.max() <= 0.07
    assert delays.min() < 0.052 and delays.max() > 0.068, "uniform over the width, not a point"
    assert np.all(delays == np.round(delays, 9)), "rounded to 1 ns"
    assert [Link(0.05).draw(0, k) for k in range(5)] == [0.05] * 5, "no jitter: the fixed delay"


def test_loss_is_drawn_with_its_probability_and_zero_and_one_are_exact():
    draws = [Link(0.0, 0.0, 0.2, seed=1).draw(0, k) for k in range(5000)]
    lost = sum(d is None for d in draws)
    assert abs(lost / 5000 - 0.2) < 4 * math.sqrt(0.2 * 0.8 / 5000), f"{lost} of 5000 lost"
    assert all(d == 0.0 for d in draws if d is not None)
    assert all(Link(0.0, 0.0, 1.0).draw(0, k) is None for k in range(100))
    assert not NO_LINK.active and NO_LINK.draw(0, 0) == 0.0


@pytest.mark.parametrize("kwargs", [{"delay_s": -0.1}, {"jitter_s": math.nan}, {"loss": 1.5}, {"seed": -1}])
def test_a_link_out_of_range_is_refused(kwargs):
    with pytest.raises(ValueError, match="link"):
        Link(**kwargs)


def test_per_generator_values_apply_to_their_generator():
    link = Link((0.01, 0.2))
    assert (link.draw(0, 0), link.draw(1, 0)) == (0.01, 0.2)


# --- the delay line ----------------------------------------------------------------------


def test_a_delay_line_cuts_each_period_where_answers_take_effect():
    line = DelayLine(Link(0.03), [0.0])  # 1.5 periods of 20 ms
    pieces = []
    for k in range(3):
        line.send(0, k, k * 0.02, float(k + 1), k * 0.02)
        pieces += [(round(a, 9), round(b, 9), line.powers[0]) for a, b in line.pieces(k * 0.02, (k + 1) * 0.02)]
    assert pieces == [(0.0, 0.02, 0.0), (0.02, 0.03, 0.0), (0.03, 0.04, 1.0), (0.04, 0.05, 1.0),
                      (0.05, 0.06, 2.0)]
    assert line.powers == [2.0], "the answer to sample 1 took effect at 0.05 s, at the end of the last piece"


def test_a_lost_answer_leaves_the_command_in_force():
    line = DelayLine(Link(0.0, 0.0, 1.0), [0.4])
    assert line.send(0, 0, 0.0, 0.9, 0.0) is None and line.powers == [0.4] and line.lost == [1]


def test_with_jitter_the_answer_to_the_latest_measurement_arrived_is_in_force_and_older_ones_are_superseded():
    link, period, n = Link(0.01, 0.08, seed=5), 0.02, 60  # jitter of 4 periods reorders answers
    effects = [k * period + link.draw(0, k) for k in range(n)]
    line, in_force = DelayLine(link, [-1.0]), []
    for k in range(n):
        line.send(0, k, k * period, float(k), k * period)
        list(line.pieces(k * period, (k + 1) * period))
        in_force.append(line.powers[0])
    expected = [max([j for j in range(n) if effects[j] <= (k + 1) * period], default=-1) for k in range(n)]
    assert in_force == expected
    overtaken = sum(any(effects[j] <= effects[k] for j in range(k + 1, n)) for k in range(n)
                    if effects[k] <= n * period)
    assert line.superseded == [overtaken] and overtaken > 5


def test_without_a_link_every_answer_takes_effect_at_once_and_a_period_is_one_piece():
    line = DelayLine(NO_LINK, [0.0])
    assert line.send(0, 4, 0.08, 0.25, 0.08) == 0.08 and line.powers == [0.25]
    assert list(line.pieces(0.08, 0.1)) == [(0.08, 0.1)]


# --- the reporting core ------------------------------------------------------------------


def test_lockstep_applies_an_answer_from_its_measurements_instant_plus_the_delay():
    loop = LockstepStepper(integrate, [], [paired_channel()], 0.06, 0.02, 1.0, Link(0.025))
    loop.start(0)
    for k in range(3):
        loop.sent(k * MS)
        verdict, output = loop.command(0, k * 20 * MS, 0.1 * (k + 1), k * MS + 1)
        assert verdict is Verdict.APPLIED and output is not None, "the handshake completes at the answer"
    assert loop.state == [(0.0, 0.02, (0.0,)), (0.02, 0.025, (0.0,)), (0.025, 0.04, (0.1,)), (0.04, 0.045, (0.1,)),
                          (0.045, 0.06, (0.2,))]
    assert output.done and output.states[-1].powers == (0.2,), "the answer to sample 2 never took effect"
    assert loop.link_summary(0)["link_lost"] == 0


def test_lockstep_with_a_lost_answer_steps_on_with_the_command_in_force():
    loop = LockstepStepper(integrate, [], [paired_channel()], 0.04, 0.02, 1.0, Link(0.0, 0.0, 1.0))
    loop.start(0)
    loop.sent(0)
    _, output = loop.command(0, 0, 0.5, 1)
    assert output is not None and loop.state == [(0.0, 0.02, (0.0,))] and loop.link_summary(0)["link_lost"] == 1
    assert loop.channels[0].stats.deadline_misses == 0


def test_realtime_holds_an_answer_until_its_instant_on_the_reporting_grid():
    loop = RealtimeReporter(integrate, [], [paired_channel()], 0.0, 1_000 * MS, 20 * MS, 0.1, Link(0.03))
    loop.start(1_000 * MS)
    loop.command(0, 1_000 * MS, 0.25, 1_005 * MS)  # arrives at 5 ms, due at 30 ms
    assert loop.state == [(0.0, 0.005, (0.0,)), (0.005, 0.02, (0.0,))], "integrated ahead with 0 still in force"
    loop.on_timer(1_020 * MS)
    loop.command(0, 1_020 * MS, -0.1, 1_024 * MS)  # due at 50 ms
    assert loop.state[-3:] == [(0.02, 0.024, (0.0,)), (0.024, 0.03, (0.0,)), (0.03, 0.04, (0.25,))]


def test_realtime_losses_in_a_row_decay_the_power_as_silence_does():
    loop = RealtimeReporter(integrate, [], [paired_channel()], 0.0, 1_000 * MS, 20 * MS, 0.1, Link(0.0, 0.0, 1.0))
    loop.start(1_000 * MS)
    loop.line.force(0, -1, 0.3)  # a power in force, then every answer lost
    for k in range(1, 8):
        loop.on_timer(1_000 * MS + k * 20 * MS)
        loop.command(0, 1_000 * MS + k * 20 * MS, 0.5, 1_000 * MS + k * 20 * MS + MS)
    assert loop.channels[0].power_pu == 0.0 and loop.channels[0].stats.command_timeouts == 1


# --- the offline loop --------------------------------------------------------------------


def test_offline_sampled_with_a_one_period_delay_applies_each_command_one_period_later():
    """Against a loop written out here: the law's command of sample k held over [t_k+1, t_k+2)."""
    plant, ctrl, rate = SmibParams(), ControllerParams(battery_limit_pu=0.3), 50.0
    traj = simulate_sampled(plant, ctrl, InitialAngle(), 2.0, rate, 1e-3, Link(1.0 / rate))
    law, x, power, period = SampledController(plant, ctrl, 1.0 / rate), InitialAngle().initial_state(plant), 0.0, 0.02
    expected = [x[0]]
    for k in range(100):
        command, _, _ = law.step(float(x[0]) - plant.delta_bar_rad)
        x = advance(k * period, (k + 1) * period, x, power, plant, InitialAngle(), 1e-3)
        power = command
        expected.append(x[0])
    np.testing.assert_allclose(traj.delta_rad, expected, rtol=0, atol=1e-12)


def test_the_delay_margin_scans_all_limits_together_then_bisects_each():
    tried = []
    first_loss = {0: 0.1234, 1: None, 2: 0.0}  # limit index -> first delay that slips (None: never)

    def in_sync(delay, indices):
        tried.append((delay, tuple(indices)))
        return [first_loss[i] is None or delay < first_loss[i] for i in indices]

    found = delay_margins(in_sync, [0.3, math.inf, 0.0], 0.05, 0.5, 1e-3)
    assert found[0].margin_s < 0.1234 <= found[0].slips_s and found[0].slips_s - found[0].margin_s <= 1e-3
    assert tried[:4] == [(0.0, (0, 1, 2)), (0.05, (0, 1)), (0.1, (0, 1)), (0.15, (0, 1))], "one batch per delay"
    assert found[0].runs == sum(0 in indices for _, indices in tried)
    assert found[1].slips_s is None and found[1].to_json()["delay_margin_s"] is None, "no slip: no margin claimed"
    assert found[1].text() == "no margin found up to 0.5 s (in synchronism at every delay tried)"
    assert found[2].margin_s is None and found[2].runs == 1 and found[2].text().startswith("none")
