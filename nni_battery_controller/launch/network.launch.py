"""Launch a network case: the network plant, one battery controller per generator of the case, the MCAP logger.

    ros2 launch nni_battery_controller network.launch.py case:=ieee39 mode:=lockstep duration_s:=10.0 \
        battery_limit_pu:=0.1 gen_b:='3=0.2 10=inf' fault_bus:=16 clearing_time:=0.1 output_path:=ieee39.mcap

The controllers are not listed here: the case is read when the launch runs
(an OpaqueFunction), and it starts one controller node per generator, in
namespace ``/gen<i>`` (generator i in case order, where the network plant
publishes its PMU), each with g measured from its PMU and its angle from its
pre-fault value (:mod:`nni_battery_controller.network_deployment`, the same
parameters ``nni-demo --case`` gives). ``battery_limit_pu`` is every
generator's b, ``gen_b`` ('I=B ...') overrides it per generator; the gains are
the same at every generator. The disturbance arguments are the network plant
node's parameters, checked as ``nni-simulate --case`` checks its options
(``fault_bus`` empty: the case's default bus, 7 Kundur, 16 IEEE 39). Each node
reads its defaults from its package's config YAML; the launch passes only what
it sets. The launch shuts down when the plant exits: the controllers and the
logger get SIGINT, and the logger finishes the recording.

``launch`` is imported inside :func:`generate_launch_description` only, so
that :func:`network_nodes` (the nodes a launch would create, as plain dicts)
can be imported and checked where ``launch`` is not installed.
"""

from types import SimpleNamespace

import yaml

from nni_battery_controller.network_cli import make_scenario
from nni_battery_controller.network_deployment import (
    battery_limits,
    controller_parameters,
    generator_limits,
    namespaces,
    plant_parameters,
    scenario_parameters,
)
from nni_battery_controller.network_sim import NetworkLaw
from nni_msgs_adapter.ros.defaults import controller_defaults
from nni_plant_sim.cases import load_network

#: The scenarios this launch file takes arguments for (``nni-demo --case`` also runs mechanical_step and
#: angle_displacement; here they are refused, not ignored).
SCENARIOS = ("bus_fault", "line_trip")
#: Launch arguments: name -> (default, description). Numbers are read as ROS reads parameter text (YAML).
ARGUMENTS = {
    "case": ("kundur_two_area", "shipped test system (kundur_two_area, ieee39)"),
    "mode": ("lockstep", "lockstep (simulated /clock) or realtime"),
    "duration_s": ("10.0", "simulated seconds to run, then shut down"),
    "pmu_rate_hz": ("50.0", "PMU reporting rate, frames/s (and the controllers' sampling rate)"),
    "scenario": ("bus_fault", "bus_fault or line_trip"),
    "fault_bus": ("", "bus_fault: the faulted bus (empty: 7 Kundur, 16 IEEE 39)"),
    "fault_r": ("0.0", "bus_fault: fault resistance, pu system base"),
    "fault_x": ("0.0", "bus_fault: fault reactance, pu system base"),
    "clearing_time": ("0.1", "bus_fault: clearing time, s"),
    "trip_line": ("", "branch that opens, 'FROM TO [CIRCUIT]' (empty: none; line_trip needs one)"),
    "battery_limit_pu": ("0.1", "every generator's battery limit b, pu of its rating (.inf: unlimited)"),
    "gen_b": ("", "per-generator limits instead, 'I=B ...' (I: 1.. as in /gen<I>)"),
    "tau_s": (None, "tau, s, at every generator"),
    "gain_k": (None, "K, pu/rad, at every generator"),
    "gain_l": (None, "L, pu/rad, at every generator (K < L)"),
    "alpha": (None, "alpha at every generator"),
    "output_path": ("network.mcap", "the MCAP recording of every namespace"),
}
#: (package, executable) of each node.
PLANT = ("nni_plant_sim", "network_plant_node")
CONTROLLER = ("nni_battery_controller", "controller_node")
LOGGER = ("nni_msgs_adapter", "mcap_logger")


def argument_defaults() -> dict:
    """Every argument's default as launch text; the gains' from the controller's config YAML."""
    gains = controller_defaults()
    return {name: str(gains[name]) if default is None else default for name, (default, _) in ARGUMENTS.items()}


def _value(text: str):
    return yaml.safe_load(text)


def network_nodes(given: dict) -> list[dict]:
    """The nodes a launch with these argument texts creates: ``package``, ``executable``, ``name``,
    ``namespace``, ``parameters`` (one dict); the logger first, then the controllers, the plant last.

    ValueError (or CliError) naming a bad argument: an unknown case, a bus or branch not in it,
    K >= L, a bad ``gen_b`` word.
    """
    values = {**argument_defaults(), **given}
    case = values["case"]
    if values["scenario"] not in SCENARIOS:
        raise ValueError(f"scenario must be one of {', '.join(SCENARIOS)} (the launch file's arguments), "
                         f"got {values['scenario']!r}")
    net = load_network(case)
    trip = [int(word) for word in values["trip_line"].split()]
    options = SimpleNamespace(case=case, scenario=values["scenario"],
                              fault_bus=_value(values["fault_bus"]) if values["fault_bus"] else None,
                              fault_r=_value(values["fault_r"]), fault_x=_value(values["fault_x"]),
                              clearing_time=_value(values["clearing_time"]), trip_line=trip or None)
    scenario, _, _ = make_scenario(net, options)
    rate = float(_value(values["pmu_rate_hz"]))
    law = NetworkLaw.uniform(net, *(float(_value(values[name])) for name in ("tau_s", "gain_k", "gain_l", "alpha")))
    limits = battery_limits(net.size, float(_value(values["battery_limit_pu"])),
                            generator_limits(values["gen_b"].split(), net.size, "gen_b"))
    plant = plant_parameters(case, scenario_parameters(net, scenario, trip), values["mode"], rate,
                             float(_value(values["duration_s"])))
    nodes = [{"package": LOGGER[0], "executable": LOGGER[1], "name": "mcap_logger", "namespace": "",
              "parameters": {"output_path": values["output_path"]}}]
    nodes += [{"package": CONTROLLER[0], "executable": CONTROLLER[1], "name": "controller", "namespace": ns,
               "parameters": controller_parameters(net, i, limits[i], rate, law)} for i, ns in enumerate(namespaces(net))]
    nodes.append({"package": PLANT[0], "executable": PLANT[1], "name": "network_plant", "namespace": "",
                  "parameters": plant})
    return nodes


def generate_launch_description():
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler
    from launch.event_handlers import OnProcessExit
    from launch.events import Shutdown
    from launch_ros.actions import Node

    def setup(context):
        specs = network_nodes({name: context.launch_configurations[name] for name in ARGUMENTS})
        nodes = [Node(package=spec["package"], executable=spec["executable"], name=spec["name"],
                      namespace=spec["namespace"], parameters=[spec["parameters"]]) for spec in specs]
        # The run is over when the plant (the last node) exits: stop the others, finish the recording.
        return [*nodes, RegisterEventHandler(OnProcessExit(target_action=nodes[-1], on_exit=[
            EmitEvent(event=Shutdown(reason="the network plant finished its run"))]))]

    defaults = argument_defaults()
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=defaults[name], description=text)
          for name, (_, text) in ARGUMENTS.items()),
        OpaqueFunction(function=setup),
    ])
