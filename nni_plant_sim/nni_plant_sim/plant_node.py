"""Plant node: the SMIB generator with a battery, publishing PMU-style measurements.

Only what is the SMIB's own: its parameters (:mod:`.plant_config`), its physics
(:mod:`.model`, :mod:`.scenarios`, :mod:`.integrators`), its PMU's sensor
(noise and quantisation of the angle, the power it implies) and the latched
invariant set. Start-up, the reporting loop, the command path, ``start_fault``
and diagnostics are those of every plant node (:mod:`.plant_node_base`).
Topics and QoS: :mod:`nni_msgs_adapter.ros.contract`.
"""

from __future__ import annotations

import sys

from nni_msgs_adapter.ros import contract
from nni_msgs_adapter.ros.node_main import run_node
from nni_plant_sim.integrators import advance
from nni_plant_sim.model import electrical_power, invariant_set_boundary
from nni_plant_sim.phasors import frequency_hz, rocof_hz_per_s
from nni_plant_sim.plant_config import parameters, plant_from
from nni_plant_sim.plant_node_base import PlantNodeBase
from nni_plant_sim.pmu_stream import SMIB_STATION, station_values
from nni_plant_sim.scenarios import InitialAngle, from_values

#: Prefix of the JSON line with the final diagnostics values printed at exit.
SUMMARY_PREFIX = "plant_node summary: "


class PlantNode(PlantNodeBase):
    """The generator: integrates the swing equation and reports like a PMU."""

    summary_prefix = SUMMARY_PREFIX

    def __init__(self, **kwargs):
        super().__init__("plant", parameters(), **kwargs)
        self.create_publisher(*contract.endpoint(contract.TOPIC_INVARIANT_SET)).publish(
            contract.invariant_set_message(self.now_ns(), invariant_set_boundary(self._plant)))

    def _configure_plant(self, values: dict) -> None:
        self.namespaces, self._labels = ("",), ({},)
        self._plant, self._fault = plant_from(values), from_values(values)
        self._before = InitialAngle(self._plant.delta_bar_rad, 0.0)  # at rest at the equilibrium, pre-fault

    def _check(self, values: dict) -> None:
        plant_from(values), from_values(values)

    def _locked_at_start(self) -> tuple:
        return ("mode",), "once the node is up (it chose its publishers)"

    def _state_of(self, scenario):
        return scenario.initial_state(self._plant)

    def _integrate(self, t0_s: float, t1_s: float, x, powers):
        return advance(t0_s, t1_s, x, powers[0], self._plant, self._scenario, self._values["integration_step_s"])

    def _frames(self, sample) -> tuple:
        """The PMU's reading: angle and speed with their noise, the electrical power at the measured angle."""
        delta, speed = self._sensors[0].read(*sample.state.tolist())
        _, p_max = self._scenario.network(sample.t_s, self._plant)
        return ((delta, speed, float(electrical_power(delta, p_max))),)

    def _stream_description(self) -> tuple:
        """One station, the generator (no buses: its infinite bus is the reference); EMF only."""
        return (SMIB_STATION,), self._values["f0_hz"], False, "nni_plant_sim plant_node: the SMIB generator"

    def _synchrophasors(self, sample, frames, stat):
        """The EMF (1 pu) at the measured angle, FREQ from the measured speed, ROCOF of the true state, P_E, P_ST."""
        (delta, speed, p_elec), = frames
        true_delta, true_speed = sample.state.tolist()
        rocof = rocof_hz_per_s(self._plant, self._scenario.network(sample.t_s, self._plant), true_delta, true_speed,
                               sample.powers[0])
        return station_values(stat, 1.0, delta, frequency_hz(speed, self._plant.f0_hz), rocof,
                              (p_elec, sample.powers[0]))


def main(args=None) -> int:
    """``ros2 run nni_plant_sim plant_node``."""
    return run_node(PlantNode, args, prog="plant_node")


if __name__ == "__main__":
    sys.exit(main())
