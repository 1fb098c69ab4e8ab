"""The plant nodes' parameters: declared once with unit and range, and what they build.

:func:`run_parameters` are those of every plant node (time mode, start, the
batteries' rating, the PMU and its C37.118 stream, the timeouts; :mod:`nni_plant_sim.plant_node_base`
reads them); :func:`parameters` is the SMIB plant node's table, whose defaults
live in ``config/plant.yaml``, read on the first call (not at import). The
network plant's table is :mod:`nni_plant_sim.network_plant_config`.
"""

from __future__ import annotations

import functools
import math

from nni_msgs_adapter.ros.defaults import plant_defaults
from nni_msgs_adapter.ros.ros_params import Spec, allow_tuning
from nni_plant_sim.link import Link
from nni_plant_sim.model import SmibParams
from nni_plant_sim.pmu_stream import stream_parameters
from nni_plant_sim.scenarios import SCENARIOS


def run_parameters(defaults: dict) -> tuple[Spec, ...]:
    """What every plant node declares, its defaults from ``defaults`` (the node's YAML)."""
    return (
        Spec("mode", defaults["mode"], "Time mode: realtime (wall clock) or lockstep (simulated /clock).",
             choices=("realtime", "lockstep")),
        Spec("pmu_rate_hz", defaults["pmu_rate_hz"], "PMU reporting rate, frames/s (IEEE C37.118 practice: 10 to 1000).", 10.0, 1000.0),
        Spec("integration_step_s", defaults["integration_step_s"], "Largest RK4 step of the swing equation, s.", 1e-6, 0.1),
        Spec("duration_s", defaults["duration_s"], "Simulated seconds to run after the start, then exit; 0 runs until stopped.",
             0.0, 1e9),
        Spec("fault_at_start", defaults["fault_at_start"], "Start the fault scenario at t = 0; false waits for plant/start_fault."),
        Spec("wait_for_subscribers", defaults["wait_for_subscribers"], "Start only when this many subscribers listen on pmu "
             "(the controller, the logger; a network: on each generator's) and a controller publishes on battery/command; "
             "0 starts at once.", 0, 100),
        Spec("wait_for_recorders", defaults["wait_for_recorders"], "Start only when plant/state (a network: each "
             "generator's) has this many subscribers as its writer sees them: the recorders (the logger, a Rerun or "
             "Foxglove bridge). A recorder that has matched the writer may not yet be matched by it, and then misses "
             "the first states; 0: no wait.", 0, 100),
        Spec("wait_timeout_s", defaults["wait_timeout_s"], "Give up (error, non-zero exit) after waiting this long for them, s.",
             0.1, 1e6),
        Spec("discovery_settle_s", defaults["discovery_settle_s"], "Once the subscribers are there, wait this long so that every other "
             "endpoint of theirs has matched too (DDS discovery), s.", 0.0, 10.0),
        Spec("battery_rating_pu", defaults["battery_rating_pu"], "Battery inverter rating (at each generator, pu of its "
             "machine's rating): commands are clipped to +-rating, pu (.inf: unlimited; nni-demo and the launch files "
             "give b).", 0.0, math.inf),
        Spec("battery_energy_pu_s", defaults["battery_energy_pu_s"], "Battery energy (at each generator): pu s of its "
             "machine's rating it delivers from half charge, with as much room to absorb; an empty battery delivers "
             "nothing, a full one absorbs nothing (.inf: unlimited).", 1e-9, math.inf),
        Spec("command_authentication", defaults["command_authentication"], "Which battery commands count: hmac (those "
             "sealed under the run's key, NNI_COMMAND_KEY_FILE; others are dropped and counted) or none (those of the "
             "one writer on battery/command, paired at the start; none while a second writer is there).",
             choices=("hmac", "none"), read_only=True),
        Spec("hold_until_released", defaults["hold_until_released"], "Start the run only once the process gets SIGUSR1 "
             "(nni-demo and the launch files send it when every node's parameters read back as they passed them).",
             read_only=True),
        allow_tuning(defaults["allow_tuning"]),
        Spec("noise_angle_std_rad", defaults["noise_angle_std_rad"], "PMU angle noise standard deviation, rad.", 0.0, 1.0),
        Spec("noise_speed_std_rad_s", defaults["noise_speed_std_rad_s"], "PMU speed noise standard deviation, rad/s.", 0.0, 10.0),
        Spec("quantisation_rad", defaults["quantisation_rad"], "PMU angle resolution, rad (0: none).", 0.0, 1.0),
        Spec("noise_seed", defaults["noise_seed"], "Seed of the measurement noise generator (generator i of a network: "
             "seed + i - 1).", 0, 2**31 - 1),
        Spec("command_timeout_s", defaults["command_timeout_s"], "realtime: a battery command older than this (from its "
             "measurement's instant) is dropped, and the one in force decays to zero, s.", 1e-3, 100.0),
        Spec("lockstep_timeout_s", defaults["lockstep_timeout_s"], "lockstep: wall time to wait for a command before applying zero, s.",
             1e-3, 100.0),
        *link_parameters(defaults),
        *stream_parameters(defaults),
    )


@functools.cache
def parameters() -> tuple[Spec, ...]:
    """The SMIB plant's parameters, their defaults from ``config/plant.yaml`` (read once, on first use)."""
    defaults = plant_defaults()
    return (
        *run_parameters(defaults),
        Spec("inertia_h_s", defaults["inertia_h_s"], "Inertia constant H, s.", 1e-3, 1e3),
        Spec("damping_pu", defaults["damping_pu"], "Damping D, pu power per rad/s.", 0.0, 1e3),
        Spec("p_mech_pu", defaults["p_mech_pu"], "Pre-fault mechanical power P_M, pu (< P_max).", 0.0, 1e3),
        Spec("p_max_pu", defaults["p_max_pu"], "Maximum transfer P_max, pu.", 1e-6, 1e3),
        Spec("f0_hz", defaults["f0_hz"], "Nominal frequency f0, Hz.", 1.0, 1e3),
        Spec("scenario", defaults["scenario"], "Fault scenario.", choices=tuple(SCENARIOS)),
        Spec("delta0_rad", defaults["delta0_rad"], "initial_angle: rotor angle right after the fault, rad.", -10.0, 10.0),
        Spec("speed0_rad_s", defaults["speed0_rad_s"], "initial_angle: speed deviation right after the fault, rad/s.", -1e3, 1e3),
        Spec("step_p_mech_pu", defaults["step_p_mech_pu"], "mechanical_step: mechanical power during the step, pu.", 0.0, 1e3),
        Spec("step_duration_s", defaults["step_duration_s"], "mechanical_step: length of the step, s (.inf: for good).", 1e-6, math.inf),
        Spec("fault_p_max_pu", defaults["fault_p_max_pu"], "transfer_limit_fault: P_max while the fault is on, pu.", 0.0, 1e3),
        Spec("clearing_time_s", defaults["clearing_time_s"], "transfer_limit_fault: clearing time, s.", 1e-6, 1e3),
    )


def link_parameters(defaults: dict) -> tuple[Spec, ...]:
    """The communication link's parameters (:mod:`nni_plant_sim.link`); a network plant's apply to every generator."""
    return (
        Spec("link_delay_s", defaults["link_delay_s"], "Link: fixed delay from a measurement's instant to its answer "
             "taking effect, s (lockstep: simulated time; realtime: on the reporting grid).", 0.0, 10.0),
        Spec("link_jitter_s", defaults["link_jitter_s"], "Link: extra delay drawn uniform in [0, this), s.", 0.0, 10.0),
        Spec("link_loss", defaults["link_loss"], "Link: probability that an answer is lost (the command in force "
             "stays).", 0.0, 1.0),
        Spec("link_seed", defaults["link_seed"], "Link: seed of the jitter and loss draws.", 0, 2**31 - 1),
    )


def link_from(values: dict) -> Link:
    """The Link of the parameter values."""
    return Link(values["link_delay_s"], values["link_jitter_s"], values["link_loss"], values["link_seed"])


def plant_from(values: dict) -> SmibParams:
    """SmibParams from parameter values (ValueError names a violated condition)."""
    return SmibParams(values["inertia_h_s"], values["damping_pu"], values["p_mech_pu"],
                      values["p_max_pu"], values["f0_hz"])
