"""The controller node's parameters: declared once with unit and range, and the configuration they build.

Read by :mod:`nni_battery_controller.controller_node`; the defaults live in ``config/controller.yaml``,
read on the first call of :func:`parameters` (not at import).
"""

from __future__ import annotations

import functools
import math

from nni_battery_controller.law import ControllerParams
from nni_msgs_adapter.ros.defaults import controller_defaults
from nni_msgs_adapter.ros.ros_params import Spec
from nni_plant_sim.model import SmibParams


@functools.cache
def parameters() -> tuple[Spec, ...]:
    """The controller's parameters, their defaults from ``config/controller.yaml`` (read once, on first use)."""
    defaults = controller_defaults()
    return (
        Spec("tau_s", defaults["tau_s"], "Phase-lead time constant tau, s.", 1e-4, 100.0),
        Spec("gain_k", defaults["gain_k"], "Gain K, pu/rad (must be < gain_l).", 1e-6, 100.0),
        Spec("gain_l", defaults["gain_l"], "Gain L, pu/rad (must be > gain_k: stability condition K - L < 0).", 1e-6, 100.0),
        Spec("alpha", defaults["alpha"], "Saturated-mode decay factor alpha (x3' = -(alpha/K) x3).", 1e-6, 100.0),
        Spec("battery_limit_pu", defaults["battery_limit_pu"], "Battery power limit b, pu; .inf for unlimited, 0 for none.",
             0.0, math.inf),
        Spec("p_mech_pu", defaults["p_mech_pu"], "Model of the plant: pre-fault mechanical power P_M, pu.", 0.0, 1e3),
        Spec("p_max_pu", defaults["p_max_pu"], "Model of the plant: maximum transfer P_max, pu.", 1e-6, 1e3),
        Spec("inertia_h_s", defaults["inertia_h_s"], "Model of the plant: inertia H, s (for W_hat only).", 1e-3, 1e3),
        Spec("f0_hz", defaults["f0_hz"], "Model of the plant: nominal frequency, Hz (for W_hat only).", 1.0, 1e3),
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
             "angle, rad, that d is measured from (.inf, the default: not set, for model: delta_bar = asin(P_M/P_max))."),
    )


#: Live-tunable while running (validated, K < L): the law's gains. Everything else is locked once the
#: controller answers measurements: the limit b, the plant model, the rate and the input gate's bounds.
TUNABLE = ("tau_s", "gain_k", "gain_l", "alpha")


def locked_when_active() -> tuple[str, ...]:
    """The parameters locked once the controller answers measurements: all but :data:`TUNABLE`."""
    return tuple(spec.name for spec in parameters() if spec.name not in TUNABLE)


class ControllerConfig:
    """Validated configuration built from parameter values (ValueError names the problem)."""

    def __init__(self, values: dict):
        self.values = values
        self.ctrl = ControllerParams(values["tau_s"], values["gain_k"], values["gain_l"], values["alpha"],
                                     values["battery_limit_pu"])
        self.plant = SmibParams(values["inertia_h_s"], 0.0, values["p_mech_pu"], values["p_max_pu"],
                                values["f0_hz"])
        self.period_s = 1.0 / values["sample_rate_hz"]
        self.stale_after_s = values["stale_after_periods"] * self.period_s
        #: InputGate's (gap_ns, tolerance_ns, reanchor_after).
        self.gate_bounds = (round(self.stale_after_s * 1e9), round(values["stamp_tolerance_s"] * 1e9),
                            values["reanchor_after"])
