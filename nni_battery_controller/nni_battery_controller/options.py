"""Scenario, plant model and gain options shared by ``nni-simulate`` and ``nni-demo`` (and their default battery limits, the paper's); the link options of ``nni-simulate``.

One helper adds the same options, with the same names and defaults, to both
command lines; the defaults are the nodes' own (the package YAML files, read
through :mod:`nni_msgs_adapter.ros.defaults` when the parser is built, not at
import). Values are resolved in this order, later wins: the package YAML,
``--params-file`` (a ROS params file in the nodes' format), the command line.
Each value is kept under the node parameter name it sets, so that what a demo
passes to its nodes and what the assessment models are the same numbers.

An option that does not apply to the chosen scenario is refused, naming it.
Pure python: no ROS import.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path

import yaml

from nni_battery_controller.law import ControllerParams
from nni_battery_controller.laws import GAIN_PARAMETERS, GAINS, LAW_NAMES, Law, law_from_parameters
from nni_battery_controller.network_sim import NetworkLaw
from nni_msgs_adapter.ros.cli_support import CliError, finite_float, float_within, positive_float
from nni_msgs_adapter.ros.defaults import controller_defaults, plant_defaults
from nni_plant_sim.battery import battery_energy
from nni_plant_sim.link import Link
from nni_plant_sim.model import SmibParams
from nni_plant_sim.scenarios import SCENARIO_FIELDS, SCENARIOS, from_values

#: The paper's battery limits b, pu: the default --b of ``nni-simulate`` and ``nni-demo``.
PAPER_BATTERY_LIMITS = (0.0, 0.2, 0.3, math.inf)


def positive_or_inf(text: str) -> float:
    """argparse type: a number > 0, or ``inf`` (for good)."""
    if text.strip().lower() in ("inf", ".inf"):
        return math.inf
    return positive_float(text)


@dataclass(frozen=True)
class Option:
    """One command-line option and the node parameter it sets."""

    flag: str
    node: str  # "plant" or "controller"
    name: str  # the node parameter
    kind: object  # argparse type
    text: str
    scenario: str | None = None  # the scenario it belongs to (None: any)
    law: str | None = None  # the speed law whose gain it is (None: a plant value or an NNI gain)


OPTIONS = (
    Option("--delta0", "plant", "delta0_rad", finite_float, "delta(0), rad", "initial_angle"),
    Option("--speed0", "plant", "speed0_rad_s", finite_float, "delta'(0), rad/s", "initial_angle"),
    Option("--step-p-mech", "plant", "step_p_mech_pu", finite_float, "P_M during the step, pu", "mechanical_step"),
    Option("--step-duration", "plant", "step_duration_s", positive_or_inf,
           "length of the step, s ('inf': for good, which moves the equilibrium)", "mechanical_step"),
    Option("--fault-p-max", "plant", "fault_p_max_pu", finite_float, "P_max during the fault, pu",
           "transfer_limit_fault"),
    Option("--clearing-time", "plant", "clearing_time_s", positive_float, "clearing time, s", "transfer_limit_fault"),
    Option("--H", "plant", "inertia_h_s", finite_float, "inertia constant H, s"),
    Option("--D", "plant", "damping_pu", finite_float, "damping D, pu/(rad/s)"),
    Option("--P-M", "plant", "p_mech_pu", finite_float, "mechanical power P_M, pu"),
    Option("--P-max", "plant", "p_max_pu", finite_float, "maximum transfer P_max, pu"),
    Option("--f0", "plant", "f0_hz", finite_float, "nominal frequency f0, Hz"),
    Option("--tau", "controller", "tau_s", finite_float, "phase-lead time constant tau, s"),
    Option("--K", "controller", "gain_k", finite_float, "gain K, pu/rad"),
    Option("--L", "controller", "gain_l", finite_float, "gain L, pu/rad (K < L)"),
    Option("--alpha", "controller", "alpha", finite_float, "saturated-mode decay factor alpha"),
    Option("--droop-k-f", "controller", "droop_k_f", finite_float, "droop: K_f, pu power per pu frequency", law="droop"),
    Option("--vsm-h-v", "controller", "vsm_h_v_s", finite_float, "vsm: virtual inertia constant H_v, s", law="vsm"),
    Option("--vsm-d-v", "controller", "vsm_d_v", finite_float, "vsm: damping D_v, pu power per pu frequency",
           law="vsm"),
    Option("--vsm-t-f", "controller", "vsm_t_f_s", finite_float, "vsm: the derivative's filter T_f, s", law="vsm"),
    Option("--pss-k-s", "controller", "pss_k_s", finite_float, "pss: gain K_s, pu power per pu frequency", law="pss"),
    Option("--pss-t-w", "controller", "pss_t_w_s", finite_float, "pss: washout T_w, s", law="pss"),
    Option("--pss-t1", "controller", "pss_t1_s", finite_float, "pss: first lead T_1, s", law="pss"),
    Option("--pss-t2", "controller", "pss_t2_s", finite_float, "pss: first lag T_2, s", law="pss"),
    Option("--pss-t3", "controller", "pss_t3_s", finite_float, "pss: second lead T_3, s", law="pss"),
    Option("--pss-t4", "controller", "pss_t4_s", finite_float, "pss: second lag T_4, s", law="pss"),
)
#: The NNI laws' gain options (the others belong to one speed law each).
NNI_GAINS = ("tau_s", "gain_k", "gain_l", "alpha")
#: The controller's model of the plant: node parameters of the controller that must equal the plant's here.
CONTROLLER_MODEL_KEYS = ("p_mech_pu", "p_max_pu", "inertia_h_s", "f0_hz")


def _shown(value) -> str:
    """A default as --help shows it: numbers in %g, inf as 'inf'."""
    if isinstance(value, float):
        return "inf" if math.isinf(value) else f"{value:g}"
    return str(value)


def add_model_options(parser: argparse.ArgumentParser) -> None:
    """Add --scenario, its options, the plant model, the gains and --params-file to ``parser``.

    Every option's default is None on the parser (so that an option the user
    gave can be told from one they did not) and shown in its help text.
    """
    plant, ctrl = plant_defaults(), controller_defaults()
    defaults = {"plant": plant, "controller": ctrl}
    parser.add_argument("--params-file", type=Path, metavar="YAML",
                        help="ROS params file in the nodes' format (/**/plant, /**/controller sections; e.g. a "
                             "copy of the package config files): its values replace the defaults shown here, "
                             "command-line options replace its values")
    scenario = parser.add_argument_group("scenario (what happens at t = 0)")
    scenario.add_argument("--scenario", choices=tuple(SCENARIOS), default=None,
                          help=f"default: {plant['scenario']} (initial_angle: the paper's case, the fault has moved "
                               f"the rotor and cleared; mechanical_step: P_M steps for a while; "
                               f"transfer_limit_fault: P_max drops until the fault clears)")
    groups = {None: parser.add_argument_group("plant (per unit)"),
              "controller": parser.add_argument_group("controller: the law and its gains (pu of the machine's "
                                                      "rating); a speed law's gain applies to that law only")}
    add_law_option(groups["controller"])
    add_law_gain_options(groups["controller"])
    for option in OPTIONS:
        if option.law:
            continue
        group = scenario if option.scenario else groups["controller" if option.node == "controller" else None]
        where = f"{option.scenario}: " if option.scenario else ""
        group.add_argument(option.flag, dest=option.name, type=option.kind, default=None,
                           metavar=option.flag.lstrip("-").upper().replace("-", "_"),
                           help=f"{where}{option.text} (default: {_shown(defaults[option.node][option.name])})")


def add_law_option(group) -> None:
    """--law (default: the controller node's, None on the parser)."""
    group.add_argument(
        "--law", choices=LAW_NAMES, default=None,
        help=f"the battery law (default: {controller_defaults()['law']}): nni (the paper's saturated H3-hat), "
             f"nni-unsaturated (its H3, output clipped at b), droop (fast frequency response), vsm (virtual inertia "
             f"and damping), pss (PSS1A on speed); docs/laws.md")


#: The speed laws' gain options (``nni-simulate --case`` and the network demo add these beside their own).
LAW_GAIN_OPTIONS = tuple(o for o in OPTIONS if o.law)


def add_law_gain_options(group) -> None:
    """The speed laws' gain options, defaults (None on the parser) from the controller node's YAML."""
    defaults = controller_defaults()
    for option in LAW_GAIN_OPTIONS:
        group.add_argument(option.flag, dest=option.name, type=option.kind, default=None,
                           metavar=option.flag.lstrip("-").upper().replace("-", "_"),
                           help=f"{option.text} (default: {_shown(defaults[option.name])})")


def speed_law_gains(args, laws) -> dict:
    """``{law: its gains}`` for the speed laws among ``laws`` from the options given and the YAML; CliError
    for an option of a law not among them or a bad value."""
    values = controller_defaults()
    for option in LAW_GAIN_OPTIONS:
        value = getattr(args, option.name, None)
        if value is None:
            continue
        if option.law not in laws:
            raise CliError(f"{option.flag} applies to --law {option.law}, not {', '.join(laws)}")
        values[option.name] = value
    try:
        return {name: law_from_parameters(name, values, ControllerParams()).gains for name in laws if name in GAINS}
    except ValueError as error:
        raise CliError(str(error)) from None


#: The network commands' NNI gain options: (dest, flag, controller parameter); one value or one per generator.
NETWORK_NNI_GAINS = (("tau", "--tau", "tau_s"), ("gain_k", "--K", "gain_k"), ("gain_l", "--L", "gain_l"),
                     ("alpha", "--alpha", "alpha"))


def add_network_law_options(parser, laws_option: bool = False) -> None:
    """--law, the NNI gains (one value or one per generator) and the speed laws' gains of the network commands."""
    group = parser.add_argument_group("controller: the law and its gains (pu of each machine's rating; the NNI gains "
                                      "one value or one per generator; default: the controller node's)")
    add_law_option(group)
    for dest, flag, text in zip((d for d, _, _ in NETWORK_NNI_GAINS), (f for _, f, _ in NETWORK_NNI_GAINS),
                                ("tau, s", "K, pu/rad", "L, pu/rad (K < L each)", "alpha")):
        group.add_argument(flag, dest=dest, type=positive_float, nargs="+", default=None, help=f"nni laws: {text}")
    add_law_gain_options(group)


def network_laws_of(args, net, reference: str, names) -> dict:
    """``{law name: NetworkLaw}`` for the laws ``names`` at every generator of ``net``, gains from the options
    given and the controller node's YAML; CliError (one line) for a gain of a law not among them or a bad value."""
    defaults = controller_defaults()
    if not any(name in ("nni", "nni-unsaturated") for name in names):
        for dest, flag, _ in NETWORK_NNI_GAINS:
            if getattr(args, dest) is not None:
                raise CliError(f"{flag} is a gain of the NNI laws, not of --law {', '.join(names)}")
    speed = speed_law_gains(args, names)
    nni = [defaults[key] if getattr(args, dest) is None else getattr(args, dest) for dest, _, key in NETWORK_NNI_GAINS]
    try:
        return {name: NetworkLaw.uniform(net, *nni, reference=reference, name=name, gains=speed.get(name))
                for name in names}
    except ValueError as error:
        raise CliError(str(error)) from None


@dataclass(frozen=True)
class ModelValues:
    """The resolved values, keyed by node parameter name, of the plant and the controller."""

    plant: dict
    controller: dict

    @property
    def scenario_name(self) -> str:
        return self.plant["scenario"]

    def smib(self) -> SmibParams:
        """The plant model (ValueError naming a bad value)."""
        p = self.plant
        return SmibParams(p["inertia_h_s"], p["damping_pu"], p["p_mech_pu"], p["p_max_pu"], p["f0_hz"])

    def controller_params(self, b: float) -> ControllerParams:
        """The NNI gains and battery limit ``b`` (ValueError naming a bad value)."""
        c = self.controller
        return ControllerParams(c["tau_s"], c["gain_k"], c["gain_l"], c["alpha"], b)

    @property
    def law_name(self) -> str:
        return self.controller["law"]

    def law(self, b: float, name: str | None = None) -> Law:
        """The law (``name``, default the chosen one) with its gains and battery limit ``b``."""
        return law_from_parameters(name or self.law_name, self.controller, self.controller_params(b))

    def law_gain_values(self, name: str | None = None) -> dict:
        """The chosen law's gains by node parameter name (what a run says ran)."""
        name = name or self.law_name
        keys = GAIN_PARAMETERS[name] if name in GAIN_PARAMETERS else NNI_GAINS
        return {k: self.controller[k] for k in keys}

    def validate(self) -> None:
        """ValueError naming the first bad value of the plant, the gains or the scenario."""
        self.smib()
        self.controller_params(math.inf)
        self.law(math.inf)
        self.scenario()

    def scenario(self):
        """The scenario object (:func:`nni_plant_sim.scenarios.from_values`)."""
        return from_values(self.plant)

    def scenario_values(self) -> dict:
        """``{"name": ..., <the scenario's own values>}``."""
        return {"name": self.scenario_name, **{k: self.plant[k] for k in SCENARIO_FIELDS[self.scenario_name]}}

    def plant_node_parameters(self) -> dict:
        """What the plant node must be given to run this model and scenario."""
        keys = ("scenario", *SCENARIO_FIELDS[self.scenario_name],
                *(o.name for o in OPTIONS if o.node == "plant" and not o.scenario))
        return {k: self.plant[k] for k in keys}

    def controller_node_parameters(self) -> dict:
        """What the controller node must be given: its law, gains and model of the plant (the plant's values)."""
        return {"law": self.law_name, **{o.name: self.controller[o.name] for o in OPTIONS if o.node == "controller"},
                **{k: self.plant[k] for k in CONTROLLER_MODEL_KEYS}}

    def header(self) -> str:
        """One line naming the scenario and its values, the plant and the gains."""
        p, c = self.plant, self.controller
        name = self.scenario_name
        if name == "initial_angle":
            what = f"delta(0) = {p['delta0_rad']:g} rad, delta'(0) = {p['speed0_rad_s']:g} rad/s"
        elif name == "mechanical_step":
            length = ("for good: the equilibrium moves" if math.isinf(p["step_duration_s"])
                      else f"for {p['step_duration_s']:g} s")
            what = f"P_M = {p['step_p_mech_pu']:g} pu {length}"
        else:
            what = f"P_max = {p['fault_p_max_pu']:g} pu until cleared at {p['clearing_time_s']:g} s"
        if self.law_name in GAIN_PARAMETERS:
            gains = f"law {self.law_name}: " + ", ".join(f"{k} {c[k]:g}" for k in GAIN_PARAMETERS[self.law_name])
        else:
            gains = (f"law {self.law_name}: tau {c['tau_s']:g} s, K {c['gain_k']:g}, L {c['gain_l']:g}, "
                     f"alpha {c['alpha']:g}")
        return (f"{name} ({what}); H {p['inertia_h_s']:g} s, D {p['damping_pu']:g}, P_M {p['p_mech_pu']:g}, "
                f"P_max {p['p_max_pu']:g}, f0 {p['f0_hz']:g} Hz; {gains}")


def _params_file_values(path: Path, prog: str) -> dict:
    """``{"plant": {...}, "controller": {...}}`` from a ROS params file, checked key by key."""
    try:
        with open(path) as handle:
            content = yaml.safe_load(handle)
    except yaml.YAMLError as exc:
        raise CliError(f"--params-file {path}: not YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(content, dict):
        raise CliError(f"--params-file {path}: expected node sections such as '/**/plant:'")
    known = {"plant": plant_defaults(), "controller": controller_defaults()}
    settable = {"plant": {"scenario", *(n for f in SCENARIO_FIELDS.values() for n in f),
                          *(o.name for o in OPTIONS if o.node == "plant")},
                "controller": {"law", *(o.name for o in OPTIONS if o.node == "controller"), *CONTROLLER_MODEL_KEYS}}
    found = {"plant": {}, "controller": {}}
    for key, section in content.items():
        node = str(key).rstrip("/").rsplit("/", 1)[-1]
        parameters = section.get("ros__parameters") if isinstance(section, dict) else None
        if node not in found or not isinstance(parameters, dict):
            raise CliError(f"--params-file {path}: section {key!r} is not '/**/plant' or '/**/controller' "
                           f"with ros__parameters")
        for name, value in parameters.items():
            if name not in known[node]:
                raise CliError(f"--params-file {path}: {node} has no parameter {name!r}")
            if name not in settable[node]:
                raise CliError(f"--params-file {path}: {node}.{name} does not apply to {prog} "
                               f"(it takes the scenario, plant model and gains; see --help for the rest)")
            expected = str if name in ("scenario", "law") else float
            if isinstance(value, bool) or not isinstance(value, (int, float) if expected is float else str):
                raise CliError(f"--params-file {path}: {node}.{name} must be a "
                               f"{'string' if expected is str else 'number'}, got {value!r}")
            found[node][name] = expected(value)
    return found


def resolve_model(args: argparse.Namespace, prog: str) -> ModelValues:
    """The values the options describe (defaults < --params-file < command line), checked.

    CliError (one line) for a command-line option that does not apply to the
    chosen scenario, for a bad params file, or for a controller model in the
    file that differs from the plant (this study models the controller with
    the plant's own values).
    """
    plant, controller = plant_defaults(), controller_defaults()
    if args.params_file is not None:
        from_file = _params_file_values(args.params_file, prog)
        plant.update(from_file["plant"])
        controller.update(from_file["controller"])
        for name in CONTROLLER_MODEL_KEYS:
            if name in from_file["controller"] and controller[name] != float(plant[name]):
                raise CliError(f"--params-file {args.params_file}: controller.{name} = {controller[name]:g} "
                               f"differs from the plant's {plant[name]:g}; {prog} models the controller with "
                               f"the plant's own values")
    if args.scenario is not None:
        plant["scenario"] = args.scenario
    if plant["scenario"] not in SCENARIOS:
        raise CliError(f"scenario must be one of {', '.join(SCENARIOS)}, got {plant['scenario']!r}")
    if getattr(args, "law", None) is not None:
        controller["law"] = args.law
    if controller["law"] not in LAW_NAMES:
        raise CliError(f"law must be one of {', '.join(LAW_NAMES)}, got {controller['law']!r}")
    laws = getattr(args, "laws_compared", None) or (controller["law"],)
    for option in OPTIONS:
        value = getattr(args, option.name)
        if value is None:
            continue
        if option.scenario and option.scenario != plant["scenario"]:
            raise CliError(f"{option.flag} applies to --scenario {option.scenario}, not {plant['scenario']}")
        if option.law and option.law not in laws:
            raise CliError(f"{option.flag} applies to --law {option.law}, not {', '.join(laws)}")
        if option.name in NNI_GAINS and not any(name.startswith("nni") for name in laws):
            raise CliError(f"{option.flag} is a gain of the NNI laws, not of --law {', '.join(laws)}")
        (plant if option.node == "plant" else controller)[option.name] = value
    for name in CONTROLLER_MODEL_KEYS:
        controller[name] = plant[name]
    return ModelValues(plant, controller)



#: The link options of ``nni-simulate`` (SMIB and ``--case``); they model the plant nodes' link_* parameters.
LINK_OPTIONS = ("link_delay", "link_jitter", "link_loss", "link_seed")


def energy_option(text: str) -> float:
    """argparse type of --battery-energy-pu-s: a number > 0 (``inf``: unlimited)."""
    try:
        return battery_energy(float(text))
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error) if "energy" in str(error) else f"expected a number, got {text!r}")


def add_energy_option(parser, where: str) -> None:
    """--battery-energy-pu-s (None on the parser: unlimited); ``where``: what takes it, for its help."""
    parser.add_argument("--battery-energy-pu-s", type=energy_option, default=None, metavar="E",
                        help="a battery of finite energy: E pu s (of the machine's rating) to deliver and as much room "
                             f"to absorb, from half charge; empty it delivers nothing ({where}; default: unlimited)")


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value < 2**31:
        raise argparse.ArgumentTypeError(f"expected an integer 0..{2**31 - 1}, got {text!r}")
    return value


def add_link_options(parser: argparse.ArgumentParser) -> None:
    """--link-delay/--link-jitter/--link-loss/--link-seed (None when not given, so that one that does not apply is refused)."""
    group = parser.add_argument_group(
        "communication link (the plant nodes' link_* parameters): the answer to measurement k takes effect at "
        "t_k + delay + jitter u_k (u_k uniform in [0, 1), seeded by (seed, generator, k)), or is lost with the "
        "given probability and the command in force stays")
    group.add_argument("--link-delay", type=float_within(0.0, 10.0, "s"), metavar="S",
                       help="fixed measurement-to-command delay, s (default 0)")
    group.add_argument("--link-jitter", type=float_within(0.0, 10.0, "s"), metavar="S",
                       help="extra delay uniform in [0, S), s (default 0)")
    group.add_argument("--link-loss", type=float_within(0.0, 1.0, "(a probability)"), metavar="P",
                       help="probability that an answer is lost (default 0)")
    group.add_argument("--link-seed", type=_seed, metavar="N", help="seed of the jitter and loss draws (default 0)")


def given_link_options(args: argparse.Namespace) -> list[str]:
    """The link options given on the command line, as typed (``--link-delay``)."""
    return [f"--{name.replace('_', '-')}" for name in LINK_OPTIONS if getattr(args, name) is not None]


def link_of(args: argparse.Namespace) -> Link:
    """The Link the options describe (defaults: none)."""
    return Link(args.link_delay or 0.0, args.link_jitter or 0.0, args.link_loss or 0.0, args.link_seed or 0)
