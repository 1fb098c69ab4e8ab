"""The network plant node's parameters: declared once with unit and range, and the disturbance they describe.

Read by :mod:`nni_plant_sim.network_plant_node`; the defaults live in
``config/network_plant.yaml``, read on the first call of :func:`parameters`
(not at import). The scenario options are the offline ``nni-simulate --case``
ones (:data:`nni_plant_sim.network_scenarios.SCENARIO_PARAMETERS`).
"""

from __future__ import annotations

import functools
import math

from nni_msgs_adapter.ros.defaults import load_defaults
from nni_msgs_adapter.ros.ros_params import Spec
from nni_plant_sim import network_scenarios
from nni_plant_sim.cases import CASES
from nni_plant_sim.plant_config import run_parameters


def defaults() -> dict:
    """The network plant's defaults (``nni_plant_sim/config/network_plant.yaml``)."""
    return load_defaults("nni_plant_sim", "network_plant.yaml", "network_plant")


@functools.cache
def parameters() -> tuple[Spec, ...]:
    """The node's parameter table (what ``--help`` lists), its defaults from the YAML (read once, on first use)."""
    values = defaults()
    return (
        Spec("case", values["case"], "Shipped test system.", choices=tuple(CASES)),
        *run_parameters(values),
        Spec("battery_ratings_pu", values["battery_ratings_pu"], "Each generator's battery rating instead, pu of its "
             "machine's rating, in case order (.inf: unlimited); empty: battery_rating_pu at every generator.",
             array_of=float),
        Spec("scenario", values["scenario"], "Disturbance at the start (t = 0, or at plant/start_fault).",
             choices=network_scenarios.NETWORK_SCENARIOS),
        Spec("fault_bus", values["fault_bus"], "bus_fault: the faulted bus (case numbering).", 1, 100000),
        Spec("fault_r", values["fault_r"], "bus_fault: fault resistance, pu (system base).", 0.0, 1e6),
        Spec("fault_x", values["fault_x"], "bus_fault: fault reactance, pu (system base).", -1e6, 1e6),
        Spec("clearing_time", values["clearing_time"], "bus_fault: clearing time, s.", 1e-6, 1e3),
        Spec("trip_line", values["trip_line"], "bus_fault, line_trip: the branch that opens (at clearing, or at the "
             "start for line_trip): 'FROM TO [CIRCUIT]'; empty for none."),
        Spec("step_p_mech", values["step_p_mech"], "mechanical_step: the machine's mechanical power during the step, "
             "pu of its rating.", 0.0, 100.0),
        Spec("step_duration", values["step_duration"], "mechanical_step: length of the step, s (.inf: for good).",
             1e-6, math.inf),
        Spec("displace", values["displace"], "angle_displacement: rad added to the machines' angles.", -10.0, 10.0),
        Spec("machine", values["machine"], "mechanical_step (one), angle_displacement: generator bus numbers.",
             array_of=int),
    )


def battery_ratings(values: dict, size: int) -> list[float]:
    """The rating of each of ``size`` generators (ValueError for a list of another length or a rating below 0)."""
    ratings = list(values["battery_ratings_pu"]) or [values["battery_rating_pu"]] * size
    if len(ratings) != size:
        raise ValueError(f"battery_ratings_pu must have one rating per generator ({size}), got {len(ratings)}")
    if not all(rating >= 0 for rating in ratings):  # NaN fails too
        raise ValueError(f"battery_ratings_pu must be >= 0 (.inf: unlimited), got {ratings}")
    return [float(rating) for rating in ratings]


def scenario_from(net, values: dict):
    """The disturbance the parameters describe (ValueError names what is wrong, missing or does not apply).

    A scenario option given (not at its default) for a scenario it does not belong to is refused.
    """
    default = {spec.name: spec.default for spec in parameters()}
    foreign = [f"{name} ({', '.join(scenarios)} only)" for name, scenarios in network_scenarios.SCENARIO_PARAMETERS.items()
               if values["scenario"] not in scenarios and _listed(values[name]) != _listed(default[name])]
    if foreign:
        raise ValueError(f"not for scenario {values['scenario']}: {', '.join(foreign)}")
    return network_scenarios.from_values(net, values)


def _listed(value):
    """An array parameter as a list (rclpy gives array.array or list), anything else as it is."""
    return value if isinstance(value, (str, bool, int, float)) else list(value)
