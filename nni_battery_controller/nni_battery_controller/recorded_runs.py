"""A recorded run as the trajectory the assessments judge: the one conversion of a recording into the physics.

The recording layer (:mod:`nni_msgs_adapter.recording.runs`, ``network_runs``)
reads the samples and knows nothing of the simulations; this module, a layer
above both, makes of them the :class:`simulate.Trajectory` that ``assess``
judges and the :class:`network_sim.NetworkTrajectory` that ``assess_network``
judges, for the demo's summaries and for replay's verdicts and figures.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from nni_battery_controller.network_sim import NetworkTrajectory
from nni_battery_controller.simulate import Trajectory
from nni_msgs_adapter.recording.network_runs import NetworkRun, network_run
from nni_msgs_adapter.recording.runs import GeneratorRun, RecordingError
from nni_msgs_adapter.ros import contract


def sampled_trajectory(run: GeneratorRun, plant, ctrl) -> Trajectory:
    """The run as the sampled :class:`Trajectory` that ``assess`` judges.

    ``plant`` (:class:`nni_plant_sim.model.SmibParams`) and ``ctrl``
    (:class:`nni_battery_controller.law.ControllerParams`) are the parameters the
    run was made with; x3, w and saturation come from ``controller/state``
    (NaN / False where the controller did not report).
    """
    return Trajectory(plant, ctrl, run.t_s, run.delta_rad, run.speed_rad_s, run.signals["x3"], run.battery_power_pu,
                      run.signals["w"], run.saturated, np.empty(0))


def network_run_trajectory(run: NetworkRun) -> NetworkTrajectory:
    """A network run as one :class:`NetworkTrajectory` (R = 1, powers on the system base)."""
    scale = run.net.mbase_mva / run.net.base_mva
    power = run.battery_power_pu * scale
    known = np.where(np.isnan(run.limits_pu), 0.0, run.limits_pu)
    return NetworkTrajectory(run.net, run.t_s, run.delta_rad[:, :, None], run.speed_rad_s[:, :, None],
                             power[:, :, None], np.zeros_like(power)[:, :, None], run.saturated[:, :, None],
                             (known * scale)[:, None])


def network_trajectory(runs: dict[str, GeneratorRun], net, namespaces, limits_pu_mbase) -> NetworkTrajectory:
    """The generators of one network run as a one-run :class:`NetworkTrajectory`.

    ``namespaces[i]`` holds generator i of ``net`` (:class:`nni_plant_sim.network.Network`);
    ``limits_pu_mbase`` (N,) are their battery limits in pu of each machine's rating.
    Powers are recorded in pu of each machine's rating and converted to the system
    base, as the offline simulation keeps them.

    Raises
    ------
    RecordingError
        If a namespace is missing or the generators were not recorded at the same instants.
    """
    missing = [ns for ns in namespaces if ns not in runs]
    if missing:
        raise RecordingError(f"no {contract.TOPIC_PLANT_STATE} in namespace(s) {', '.join(missing)}")
    chosen = [runs[ns] for ns in namespaces]
    stamps = chosen[0].stamp_ns
    uneven = [run.namespace for run in chosen if not np.array_equal(run.stamp_ns, stamps)]
    if uneven:
        raise RecordingError(f"{', '.join(uneven)} recorded other instants than {chosen[0].namespace} "
                             f"({', '.join(str(run.stamp_ns.size) for run in chosen)} states)")
    run = network_run(net, dict(zip(namespaces, chosen)))
    return network_run_trajectory(replace(run, limits_pu=np.asarray(limits_pu_mbase, dtype=float)))
