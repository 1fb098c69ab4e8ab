"""Network plant node: every generator of a multi-machine case in one process, each reporting like the SMIB plant.

One coupled physical system (:mod:`.network`, :mod:`.network_scenarios`,
:func:`.integrators.advance`) behind the reporting loop of every plant node
(:mod:`.plant_node_base`: lockstep, a sample advances only when every
generator's controller has answered it, each missing answer timing out after
``lockstep_timeout_s`` and counted in that generator's ``deadline_misses``;
realtime, the PMU grid on the wall clock). Generator i (case order) lives under
the namespace ``/gen<i>`` (``gen1`` .. ``genN``; the log names which machine is
which) and has the SMIB plant's message contract there: ``/gen<i>/pmu``,
``/gen<i>/plant/state``, ``/gen<i>/battery/command``, and its own status
``gen<i>/plant`` on ``/diagnostics``. Powers on the wire (P_E, P_ST, the
battery ratings: ``battery_ratings_pu``, one per generator) are in pu of the machine's rating, so one generator's topics
look like a SMIB's; angles are the case's (the slack's reference at the load
flow). Scenarios ``bus_fault``, ``line_trip``, ``mechanical_step`` and
``angle_displacement`` with the offline ``nni-simulate --case`` option names as
parameters, from the pre-fault equilibrium at t = 0 (``fault_at_start``) or at
the ``plant/start_fault`` service call. PMU noise per generator (its own seed);
P_E is that of the true state. Its C37.118 stream has a station per generator
(``gen<i> G<i> bus <bus>``) with the EMF at the measured angle and the terminal
voltage and current of the true state (:func:`.phasors.terminal_phasors`).
"""

from __future__ import annotations

import sys

import numpy as np

from nni_msgs_adapter.ros.node_main import run_node
from nni_plant_sim.cases import load_network
from nni_plant_sim.integrators import advance
from nni_plant_sim.network import electrical_power
from nni_plant_sim.network_plant_config import battery_ratings, parameters, scenario_from
from nni_plant_sim.network_scenarios import AngleDisplacement
from nni_plant_sim.phasors import frequency_hz, rocof_hz_per_s, terminal_phasors
from nni_plant_sim.plant_node_base import PlantNodeBase
from nni_plant_sim.pmu_stream import network_station_names, station_values

#: Prefix of the JSON line with every generator's final diagnostics values, printed at exit.
SUMMARY_PREFIX = "network_plant_node summary: "


class NetworkPlantNode(PlantNodeBase):
    """Integrates the network; publishes per generator in its namespace; steps when every controller answered."""

    summary_prefix = SUMMARY_PREFIX

    def __init__(self, **kwargs):
        super().__init__("network_plant", parameters(), **kwargs)
        self.get_logger().info(", ".join(f"/{ns}: {name}" for ns, name in zip(self.namespaces, self._plant.names)))

    def _configure_plant(self, values: dict) -> None:
        self._plant = net = load_network(values["case"])
        self._fault = scenario_from(net, values)
        self._before = AngleDisplacement(np.zeros(net.size))  # none: at rest at the equilibrium, pre-fault
        self._scale = net.mbase_mva / net.base_mva  # pu of machine rating -> pu of the system base
        self.namespaces = tuple(f"gen{i + 1}" for i in range(net.size))
        self._labels = tuple({"machine": name} for name in net.names)

    def _ratings(self, values: dict) -> list[float]:
        """``battery_ratings_pu``, one per generator, or ``battery_rating_pu`` at each."""
        return battery_ratings(values, self._plant.size)

    def _check(self, values: dict) -> None:
        """Nothing to build: every parameter is locked once the node is up."""

    def _locked_at_start(self) -> tuple:
        return [spec.name for spec in parameters()], "once the node is up (read at start)"

    def _state_of(self, scenario):
        """The scenario's initial state as one run of a batch (shape (2, N, 1)), as the offline simulation's."""
        return scenario.initial_state(self._plant)[:, :, None]

    def _integrate(self, t0_s: float, t1_s: float, x, powers):
        """The network over one period, each battery's power (pu of its machine) held, on the system base."""
        battery = (np.array(powers) * self._scale)[:, None]
        return advance(t0_s, t1_s, x, battery, self._plant, self._scenario, self._values["integration_step_s"])

    def _frames(self, sample) -> list:
        """Per generator: angle and speed as its PMU reads them, and its electrical power (pu of its rating)."""
        x = sample.state
        power = electrical_power(x[0], self._scenario.network(sample.t_s, self._plant)[1])[:, 0] / self._scale
        deltas, speeds = x.reshape(2, -1).tolist()
        if self._exact_sensors:
            return list(zip(deltas, speeds, power.tolist()))
        return [(*sensor.read(delta, speed), p) for sensor, delta, speed, p
                in zip(self._sensors, deltas, speeds, power.tolist())]

    def _stream_description(self) -> tuple:
        """A station per generator, named by its namespace, machine and bus; EMF, terminal voltage and current."""
        net = self._plant
        return (network_station_names(self.namespaces, net.names), net.f0_hz, True,
                f"nni_plant_sim network_plant_node: {self._values['case']}, {net.size} generators")

    def _synchrophasors(self, sample, frames, stat):
        """Per generator: the EMF at the measured angle, V_t and I_t (pu of the machine's rating) of the true
        state, FREQ from the measured speed, ROCOF of the true state, P_E and P_ST (pu of the machine's rating)."""
        net = self._plant
        delta, speed = sample.state.reshape(2, -1)
        p_mech, coupling = self._scenario.network(sample.t_s, net)
        emf, current, voltage = terminal_phasors(net, coupling, delta)
        measured, battery = np.array(frames), np.array(sample.powers)
        phasors = np.column_stack((emf, voltage, current / self._scale))
        angle = np.angle(phasors)
        angle[:, 0] = measured[:, 0]
        rocof = rocof_hz_per_s(net, (p_mech, coupling), delta, speed, battery * self._scale)
        return station_values(stat, np.abs(phasors), angle, frequency_hz(measured[:, 1], net.f0_hz), rocof,
                              np.column_stack((measured[:, 2], battery)))


def main(args=None) -> int:
    """``ros2 run nni_plant_sim network_plant_node``."""
    return run_node(NetworkPlantNode, args, prog="network_plant_node")


if __name__ == "__main__":
    sys.exit(main())
