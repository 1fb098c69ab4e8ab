"""Region of attraction of any law, sampled at the PMU rate: the area ``--compare-laws`` reports (issue 32).

The region of attraction of :mod:`.roa` is the paper's continuous H3-hat law's, with certificates (a sublevel set
of W, Omega) that only that law has. The comparison needs the same measure for every law at the same battery
and rate, so this sweep runs each law as the controller node runs it, sampled at the PMU rate, on the SMIB as
the one-generator case of the network code (:meth:`nni_plant_sim.network.Network.from_smib`,
:func:`.network_sim.simulate_network`, one run per initial condition, all at once). A cell of the grid is an
initial condition after the fault has cleared (angle and speed deviation; the law's state at its pre-fault
value, 0), and gets one outcome:

* ``SLIPS``: the rotor angle passed +-pi against the infinite bus at a PMU instant (as :func:`.verdicts.assess`);
* ``RETURNS``: in synchronism, and within the settling band of the equilibrium over the last settle hold of the
  horizon (settled, as the verdicts say it): a numerical outcome, not a certificate;
* ``UNDECIDED``: neither by the horizon (still swinging, or at a new equilibrium).

The network is integrated by its RK4 at :data:`STEP_S` (10 ms, the step of :mod:`.roa`'s sweep) instead of the
plant's 1 ms: ten times faster, and on the paper's case at b = 0.3 the 41 x 41 grid's outcomes of nni, droop and
pss were the same at both steps (docs/laws.md). Pure numpy: no ROS import.
"""

from __future__ import annotations

import math
import time

import numpy as np

from nni_battery_controller.network_sim import NetworkLaw, simulate_network
from nni_battery_controller.roa import RETURNS, SLIPS, UNDECIDED, Basin, RoaGrid
from nni_battery_controller.verdicts import POLE_SLIP_RAD, SETTLE_BAND_RAD, settle_hold_s
from nni_plant_sim.model import SmibParams
from nni_plant_sim.network import Network
from nni_plant_sim.network_scenarios import InitialStates

#: The comparison's grid: 41 x 41 initial conditions, angles within +-pi, speeds within +-10 rad/s (--roa's
#: ranges, coarser).
COMPARISON_GRID = RoaGrid(-math.pi, math.pi, -10.0, 10.0, 41, 41)
#: The network RK4's step in the sweep, s.
STEP_S = 1e-2
#: What each outcome means here (the JSON says it).
OUTCOME_MEANINGS = {
    "returns": "in synchronism and settled (within the settling band over the last settle hold of the horizon)",
    "slips": "the rotor angle passed +-pi against the infinite bus at a PMU instant",
    "undecided": "in synchronism but not settled by the horizon",
}


def sampled_basin(plant: SmibParams, law, grid: RoaGrid, horizon_s: float, rate_hz: float) -> Basin:
    """The :class:`.roa.Basin` of ``law`` (a :class:`.laws.Law`, its b the battery limit) on ``grid``."""
    started = time.perf_counter()
    net = Network.from_smib(plant)
    ctrl = law.ctrl
    network_law = NetworkLaw.uniform(net, ctrl.tau_s, ctrl.gain_k, ctrl.gain_l, ctrl.alpha, name=law.name,
                                     gains=law.gains)
    angle0, speed0 = grid.initial_conditions()
    traj = simulate_network(net, network_law, InitialStates(angle0[None], speed0[None]),
                            [law.limit_pu] * angle0.size, horizon_s, rate_hz, max_step_s=STEP_S)
    delta = traj.delta_rad[:, 0, :]                                  # (samples, cells)
    beyond = np.abs(delta) > POLE_SLIP_RAD
    slipped = beyond.any(axis=0)
    hold = int(math.ceil(settle_hold_s(plant) * rate_hz)) + 1
    off = np.abs(delta - plant.delta_bar_rad) > SETTLE_BAND_RAD
    returned = ~slipped & ~off[-hold:].any(axis=0)
    outcome = np.where(slipped, SLIPS, np.where(returned, RETURNS, UNDECIDED)).astype(np.int8)
    t = traj.t_s
    # Decided: the first PMU instant beyond pi; for a return, the instant it entered the band for good.
    last_off = np.where(off.any(axis=0), len(t) - 1 - np.argmax(off[::-1], axis=0), -1)
    entered = t[np.minimum(last_off + 1, len(t) - 1)]
    decided = np.where(slipped, t[np.argmax(beyond, axis=0)], np.where(returned, entered, np.nan))
    return Basin(grid, law.limit_pu, outcome.reshape(grid.shape), decided.reshape(grid.shape),
                 time.perf_counter() - started)


def roa_description(grid: RoaGrid, horizon_s: float) -> dict:
    """What a comparison's JSON says of its sweep: the grid, the horizon, the step and the outcomes' meaning."""
    return {"angle_dev_rad": [grid.angle_min_rad, grid.angle_max_rad],
            "speed_rad_s": [grid.speed_min_rad_s, grid.speed_max_rad_s], "n_angle": grid.n_angle,
            "n_speed": grid.n_speed, "cell_area_rad2_per_s": grid.cell_area, "initial_law_state": 0.0,
            "horizon_s": horizon_s, "step_s": STEP_S, "outcomes": OUTCOME_MEANINGS}
