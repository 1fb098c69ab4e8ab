"""The controller node's parameters: declared once with unit and range, and the configuration they build.

Read by :mod:`nni_battery_controller.controller_node`; the defaults live in ``config/controller.yaml``,
read on the first call of :func:`parameters` (not at import). Pure: no rclpy.

Which parameters a mode needs (:class:`ControllerConfig` refuses the others' violations only where they matter):

* ``restoring_power model`` (the SMIB): the plant model ``p_mech_pu < p_max_pu`` (d is measured from
  delta_bar = asin(P_M/P_max)), ``inertia_h_s`` and ``f0_hz`` for W_hat (``f0_hz`` also for the speed laws' dw, in every mode);
* ``restoring_power measured`` (a generator in a network): ``p_mech_pu`` (its pre-fault electrical power) and
  ``reference_angle_rad``; no SMIB model is built, so P_M >= P_max (IEEE 39's G10 carries 1.0 pu of its
  rating) is no error, and ``p_max_pu`` and ``inertia_h_s`` are not used;
* ``reference coi`` (measured only): ``coi_namespaces`` and ``coi_inertias``, with d = delta_i - delta_COI -
  ``reference_angle_rad``, the reference angle then being the generator's pre-fault angle relative to the
  centre of inertia (delta_bar_i - sum_j M_j delta_bar_j / sum_j M_j), as ``nni-simulate --reference coi``.
"""

from __future__ import annotations

import functools
import math

from nni_battery_controller.law import ControllerParams
from nni_battery_controller.laws import GAIN_PARAMETERS, LAW_NAMES, law_from_parameters
from nni_battery_controller.network_sim import ANGLE_REFERENCES
from nni_msgs_adapter.ros.defaults import controller_defaults
from nni_msgs_adapter.ros.ros_params import Spec, allow_tuning, locked_changes
from nni_plant_sim.model import SmibParams


@functools.cache
def parameters() -> tuple[Spec, ...]:
    """The controller's parameters, their defaults from ``config/controller.yaml`` (read once, on first use)."""
    defaults = controller_defaults()
    return (
        Spec("law", defaults["law"], "The battery law: nni (the paper's saturated H3-hat), nni-unsaturated (its H3, "
             "output clipped at b), droop, vsm (virtual inertia and damping) or pss (PSS1A on speed).",
             choices=LAW_NAMES),
        Spec("tau_s", defaults["tau_s"], "Phase-lead time constant tau, s.", 1e-4, 100.0),
        Spec("gain_k", defaults["gain_k"], "Gain K, pu/rad (must be < gain_l).", 1e-6, 100.0),
        Spec("gain_l", defaults["gain_l"], "Gain L, pu/rad (must be > gain_k: stability condition K - L < 0).", 1e-6, 100.0),
        Spec("alpha", defaults["alpha"], "Saturated-mode decay factor alpha (x3' = -(alpha/K) x3).", 1e-6, 100.0),
        *(Spec(name, defaults[name], f"Law {law}: {GAIN_TEXT[field]}.", *GAIN_RANGES[field])
          for law, names in GAIN_PARAMETERS.items() for name, field in names.items()),
        Spec("battery_limit_pu", defaults["battery_limit_pu"], "Battery power limit b, pu; .inf for unlimited, 0 for none.",
             0.0, math.inf),
        Spec("p_mech_pu", defaults["p_mech_pu"], "Model of the plant: pre-fault mechanical power P_M, pu.", 0.0, 1e3),
        Spec("p_max_pu", defaults["p_max_pu"], "Model of the plant: maximum transfer P_max, pu.", 1e-6, 1e3),
        Spec("inertia_h_s", defaults["inertia_h_s"], "Model of the plant: inertia H, s (for W_hat only).", 1e-3, 1e3),
        Spec("f0_hz", defaults["f0_hz"], "Model of the plant: nominal frequency, Hz (for W_hat, and the speed laws' "
             "dw = (omega - omega0)/omega0: a network's own f0 there).", 1.0, 1e3),
        Spec("sample_rate_hz", defaults["sample_rate_hz"], "PMU reporting rate the law is discretised for, frames/s.", 10.0, 1000.0),
        Spec("stale_after_periods", defaults["stale_after_periods"], "Measurements missing for this many periods: zero power, STALE.", 1, 10000),
        Spec("stamp_tolerance_s", defaults["stamp_tolerance_s"], "A measurement stamped further than this from the controller's "
             "clock (realtime: wall clock; lockstep: /clock) is implausible and dropped, s.", 1e-3, 1e6),
        Spec("reanchor_after", defaults["reanchor_after"], "After this many consecutive stamp rejections, follow the stream's "
             "clock (re-anchor, reset the law) instead of locking out.", 1, 100000),
        Spec("restoring_power", defaults["restoring_power"], "Where g comes from: model (the SMIB's g(d) from P_M, P_max) or "
             "measured (a generator in a network: g = p_mech_pu - the electrical power its PMU measured).",
             choices=("model", "measured")),
        Spec("reference_angle_rad", defaults["reference_angle_rad"], "restoring_power measured: the generator's pre-fault "
             "angle, rad, that d is measured from (.inf, the default: not set, for model: delta_bar = asin(P_M/P_max)); "
             "with reference coi, relative to the centre of inertia."),
        Spec("reference", defaults["reference"], "The angle d is measured against: pmu (the PMU's own angle) or coi "
             "(relative to the centre of inertia of the generators in coi_namespaces, from their PMUs; needs "
             "restoring_power measured).", choices=ANGLE_REFERENCES),
        Spec("coi_namespaces", defaults["coi_namespaces"], "reference coi: the generators whose pmu topics make the "
             "centre of inertia, absolute namespaces (/gen1, ...), this controller's own among them.", array_of=str),
        Spec("coi_inertias", defaults["coi_inertias"], "reference coi: their inertias M_j in coi_namespaces' order "
             "(any one unit), > 0.", array_of=float),
        Spec("authentication", defaults["authentication"], "hmac (default): every measurement, the plant's end of "
             "run and every command sealed under the run's key (NNI_COMMAND_KEY_FILE, needed); none: nothing sealed, "
             "for a plant with command_authentication none (docs/security.md).", choices=AUTHENTICATIONS),
        Spec("measurement_topic", defaults["measurement_topic"], "Where the measurements are read (relative, "
             "under each generator's namespace): pmu, the plant's own, or c37118/pmu, the same read from its "
             "IEEE C37.118 stream by the c37118_client node.", choices=MEASUREMENT_TOPICS),
        allow_tuning(defaults["allow_tuning"]),
    )


#: What each speed-law gain is (units: pu of the machine's rating; dw = (omega - omega0)/omega0) and its range.
GAIN_TEXT = {"k_f": "droop gain K_f, pu power per pu frequency", "h_v_s": "virtual inertia constant H_v, s",
             "d_v": "damping D_v, pu power per pu frequency", "t_f_s": "filter T_f of the measured derivative, s",
             "k_s": "PSS gain K_s, pu power per pu frequency", "t_w_s": "washout T_w, s", "t1_s": "lead T_1, s",
             "t2_s": "lag T_2, s", "t3_s": "lead T_3, s", "t4_s": "lag T_4, s"}
GAIN_RANGES = {"k_f": (1e-6, 1e5), "h_v_s": (0.0, 1e3), "d_v": (0.0, 1e5), "t_f_s": (1e-4, 10.0),
               "k_s": (1e-6, 1e5), "t_w_s": (1e-3, 100.0), "t1_s": (0.0, 100.0), "t2_s": (1e-4, 100.0),
               "t3_s": (0.0, 100.0), "t4_s": (1e-4, 100.0)}

#: With allow_tuning, live-tunable while running (validated, K < L): the law's gains. Everything else is locked
#: once the controller answers measurements: the limit b, the plant model, the rate and the input gate's bounds.
#: Without allow_tuning every parameter is locked from the start (:func:`.ros_params.install_validation`).
TUNABLE = ("tau_s", "gain_k", "gain_l", "alpha")


def locked_when_active() -> tuple[str, ...]:
    """The parameters locked once the controller answers measurements: all but :data:`TUNABLE`."""
    return tuple(spec.name for spec in parameters() if spec.name not in TUNABLE)


#: Read at start only: they decide which pmu topics the node subscribes to.
READ_AT_START = ("reference", "coi_namespaces", "coi_inertias", "measurement_topic", "authentication")
#: What the controller's inputs and commands are sealed with: the run's key, or nothing.
AUTHENTICATIONS = ("hmac", "none")
#: The contract's two measurement topics, TOPIC_PMU and TOPIC_C37118_PMU (the contract imports rclpy, this module
#: must not: tests/test_c37118_client_node.py checks that the names agree).
MEASUREMENT_TOPICS = ("pmu", "c37118/pmu")


def prepared(old: dict, values: dict, namespace: str, active: bool) -> "ControllerConfig":
    """The configuration of a runtime change from ``old`` to ``values``; ValueError (its reason) rejects it.

    :data:`READ_AT_START` never changes; while a run is active (the controller answers measurements)
    only :data:`TUNABLE` may change.
    """
    locked_changes(old, values, READ_AT_START, "once the node is up (its pmu subscriptions are made at start)")
    locked_changes(old, values, locked_when_active() if active else ())
    return ControllerConfig(values, namespace)


class ControllerConfig:
    """Validated configuration built from parameter values (ValueError names the problem).

    ``namespace``: the node's own (``/`` or ``/gen1``), which ``coi_namespaces`` must list.
    """

    def __init__(self, values: dict, namespace: str = "/"):
        self.values = values
        self.ctrl = ControllerParams(values["tau_s"], values["gain_k"], values["gain_l"], values["alpha"],
                                     values["battery_limit_pu"])
        #: The law with its gains and b (:mod:`.laws`).
        self.law = law_from_parameters(values["law"], values, self.ctrl)
        self.measures_power = values["restoring_power"] == "measured"
        self.p_mech_pu = values["p_mech_pu"]
        #: The SMIB model (g(d), delta_bar, W_hat); None for g measured, which uses none of it.
        self.plant = None if self.measures_power else SmibParams(
            values["inertia_h_s"], 0.0, values["p_mech_pu"], values["p_max_pu"], values["f0_hz"])
        #: The nominal frequency the speed laws' dw is measured against, rad/s.
        self.omega0_rad_s = 2.0 * math.pi * values["f0_hz"]
        self.reference_rad = reference_angle(values, self.plant)
        #: reference coi: ``(namespaces, weights M_j / sum M, own index)``, else None.
        self.coi = centre_of_inertia(values, namespace)
        #: The namespaces of the pmu topics read: the node's own ("") or, for coi, every listed generator's.
        self.pmu_namespaces = self.coi[0] if self.coi else ("",)
        self.measurement_topic = values["measurement_topic"]
        self.authenticated = values["authentication"] == "hmac"
        self.period_s = 1.0 / values["sample_rate_hz"]
        self.stale_after_s = values["stale_after_periods"] * self.period_s
        #: InputGate's (gap_ns, tolerance_ns, reanchor_after).
        self.gate_bounds = (round(self.stale_after_s * 1e9), round(values["stamp_tolerance_s"] * 1e9),
                            values["reanchor_after"])


def reference_angle(values: dict, plant: SmibParams | None) -> float:
    """The angle d is measured from: the SMIB model's delta_bar, or ``reference_angle_rad`` for g measured.

    ValueError (the reason a parameter change is rejected) when
    ``reference_angle_rad`` is missing where it is needed (.inf, the default:
    not set; not NaN, which would differ from itself in the run's lockdown
    check) or given where it does not apply.
    """
    given = values["reference_angle_rad"]
    if plant is None:
        if not math.isfinite(given):
            raise ValueError("restoring_power measured needs reference_angle_rad (the generator's pre-fault angle)")
        return given
    if given != math.inf:
        raise ValueError("reference_angle_rad applies to restoring_power measured only (the model's is asin(P_M/P_max))")
    return plant.delta_bar_rad


def check_namespaces(parameter: str, names) -> None:
    """ValueError unless ``names`` are distinct absolute namespaces (``/gen1``: a leading, no trailing slash)."""
    if len(set(names)) != len(names) or not all(name.startswith("/") and not name.endswith("/") for name in names):
        raise ValueError(f"{parameter} must be distinct absolute namespaces (/gen1, ...), got {list(names)}")


def centre_of_inertia(values: dict, namespace: str) -> tuple | None:
    """``(namespaces, weights, own index)`` for reference coi, None for pmu; ValueError for what cannot work."""
    names, inertias = values["coi_namespaces"], values["coi_inertias"]
    if values["reference"] != "coi":
        if names or inertias:
            raise ValueError("coi_namespaces and coi_inertias apply to reference coi only")
        return None
    if values["restoring_power"] != "measured":
        raise ValueError("reference coi needs restoring_power measured (a generator in a network)")
    if len(names) < 2 or len(inertias) != len(names):
        raise ValueError(f"reference coi needs coi_namespaces of at least two generators and one coi_inertias value "
                         f"each, got {len(names)} and {len(inertias)}")
    check_namespaces("coi_namespaces", names)
    if namespace not in names:
        raise ValueError(f"coi_namespaces must include this controller's own namespace {namespace}")
    if not all(math.isfinite(m) and m > 0 for m in inertias):
        raise ValueError(f"coi_inertias must be finite and positive, got {list(inertias)}")
    total = math.fsum(inertias)
    return tuple(names), tuple(m / total for m in inertias), names.index(namespace)


#: Below this (pu of the rating) a negative pre-fault power is the load flow's rounding of a unit at 0.
P_MECH_ROUNDING_PU = 1e-9


def generator_parameters(net, index: int, reference: str = "pmu") -> dict:
    """The network-specific controller parameters of generator ``index`` (case order) of ``net`` (a Network).

    g measured; ``p_mech_pu`` its pre-fault power in pu of its rating (the wire's base); the reference
    angle its load-flow angle, or for ``reference`` coi its angle relative to the centre of inertia, with
    every generator's namespace (``/gen1`` .. in case order, as the network plant names them) and inertia.
    Gains, b and the rate are the caller's.
    """
    scale = float(net.mbase_mva[index] / net.base_mva)
    p_mech = float(net.p_mech_pu[index]) / scale
    # A unit dispatched at 0 (IEEE 118's synchronous condensers) comes out of the load flow at -1e-15 or so:
    # rounding, not a motor; the parameter's range (>= 0) still refuses a real negative power.
    values = {"restoring_power": "measured", "p_mech_pu": 0.0 if -P_MECH_ROUNDING_PU < p_mech < 0.0 else p_mech}
    if reference == "coi":
        return {**values, "reference": "coi",
                "reference_angle_rad": float(net.delta_bar_rad[index]) - float(net.coi(net.delta_bar_rad)),
                "coi_namespaces": [f"/gen{j + 1}" for j in range(net.size)],
                "coi_inertias": [float(m) for m in net.inertia_m]}
    return {**values, "reference_angle_rad": float(net.delta_bar_rad[index])}
