"""``nni-simulate --tune-laws``: one search, the same budget for every law, for the gains the comparison ships.

The rule (docs/laws.md, "Fair tuning"): for each law, the candidates of its
grid (:data:`GRIDS`, :data:`BUDGET` candidates per law, every law the same
number), each run on the same SMIB, battery limit b and PMU rate. A candidate
qualifies when the scenario's run (the paper's initial-angle case by default)
settles within the run; among the qualifying ones the law's pick is the one
with the longest critical clearing time of the transfer-limit fault (the
bisection of ``--cct``), ties (equal to the bisection's tolerance) going to the
less battery energy. The speed laws ship their pick as their defaults; the NNI
laws keep the paper's gains (their results must stay the paper's), and the
search reports what the NNI law reaches on its own grid beside them.

Sensitivity, per law: the worst CCT among the pick's grid neighbours (one step
along each axis) and the share of the grid within 10 % of the pick's CCT.
Pure python: no ROS import.
"""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np

from nni_battery_controller.law_comparison import run_summary
from nni_battery_controller.laws import GAINS, Law

#: Candidates per law: every law's grid has exactly this many points.
BUDGET = 25


def _geometric(low: float, high: float, count: int) -> tuple[float, ...]:
    """``count`` points evenly spaced in log from ``low`` to ``high``, to 3 significant digits (gains people type)."""
    return tuple(float(f"{v:.3g}") for v in np.geomspace(low, high, count))


#: Two decades about the typical starting gain 100 (pu power per pu frequency), five points: 10 .. 1000.
_TWO_DECADES = _geometric(10.0, 1000.0, 5)
#: Per law, the axes searched ``{gain: values}`` (their product is the grid) and what is held ``{gain: value}``.
#: Gains are the :class:`~.laws.Law` fields: the NNI laws' in ControllerParams (tau fixed at the paper's 0.1 s,
#: alpha at 1; L over K >= 1.05 keeps the paper's condition K - L < 0), the speed laws' in their gain classes.
#: The vsm's derivative filter and the PSS's washout and lags are a device's, not tuning knobs: held. Every grid
#: holds its law's typical starting values (the NNI laws': the paper's), so no pick is worse than those.
GRIDS = {
    "nni": ({"gain_k": (0.25, 0.5, 1.0, 2.0, 4.0), "l_over_k": (1.05, 1.1, 1.5, 2.0, 4.0)},
            {"tau_s": 0.1, "alpha": 1.0}),
    "droop": ({"k_f": _geometric(10.0, 1000.0, BUDGET)}, {}),
    "vsm": ({"h_v_s": (0.0, 1.25, 2.5, 5.0, 10.0), "d_v": _TWO_DECADES}, {"t_f_s": 0.05}),
    "pss": ({"k_s": _TWO_DECADES, "t1_s": (0.05, 0.1, 0.2, 0.4, 0.8)},
            {"t_w_s": 10.0, "t2_s": 0.05, "t4_s": 0.05}),
}
GRIDS["nni-unsaturated"] = GRIDS["nni"]
#: PSS1A's two lead-lag stages are tuned as one: T3 = T1 (and T4 = T2, held).
_TIED = {"pss": {"t3_s": "t1_s"}}
#: Share of the pick's CCT that counts as "near it" in the sensitivity figure.
NEAR = 0.9


def candidates(name: str):
    """``(indices, values)`` per grid point of law ``name``: its position on each axis and its gains."""
    axes, held = GRIDS[name]
    keys = list(axes)
    for indices in itertools.product(*(range(len(axes[k])) for k in keys)):
        values = {**held, **{k: axes[k][i] for k, i in zip(keys, indices)}}
        for tied, source in _TIED.get(name, {}).items():
            values[tied] = values[source]
        yield indices, values


def law_of(name: str, values: dict, ctrl) -> Law:
    """The :class:`Law` ``name`` with the grid point's gains, b and the rest of ``ctrl`` kept."""
    if name in GAINS:
        return Law(name, ctrl, GAINS[name](**values))
    return Law(name, replace(ctrl, tau_s=values["tau_s"], alpha=values["alpha"], gain_k=values["gain_k"],
                             gain_l=values["gain_k"] * values["l_over_k"]))


def tune(name: str, ctrl, simulate_run, cct_of, tolerance_s: float) -> dict:
    """The search for law ``name`` at ``ctrl``'s b: every candidate's result, the pick and its sensitivity.

    ``simulate_run(law)`` gives ``(trajectory, scenario)``, ``cct_of(law)`` a :class:`.margins.ClearingTime`.
    """
    points = []
    for indices, values in candidates(name):
        law = law_of(name, values, ctrl)
        summary = run_summary(*simulate_run(law))
        cct = cct_of(law)
        points.append({"indices": indices, "gains": law.gain_values(), "cct_s": cct.cct_s,
                       "settled": summary["settled"], "energy_pu_s": summary["energy_pu_s"],
                       "settling_time_s": summary["settling_time_s"]})
    qualifying = [p for p in points if p["settled"]]
    if not qualifying:
        return {"law": name, "candidates": len(points), "qualifying": 0, "pick": None, "points": points}
    longest = max(p["cct_s"] for p in qualifying)
    pick = min((p for p in qualifying if p["cct_s"] >= longest - tolerance_s), key=lambda p: p["energy_pu_s"])
    neighbours = [p for p in points if sum(abs(a - b) for a, b in zip(p["indices"], pick["indices"])) == 1]
    return {"law": name, "candidates": len(points), "qualifying": len(qualifying),
            "pick": {k: pick[k] for k in ("gains", "cct_s", "energy_pu_s", "settling_time_s")},
            "worst_neighbour_cct_s": min((p["cct_s"] for p in neighbours), default=None),
            "share_near": sum(p["cct_s"] >= NEAR * pick["cct_s"] for p in points) / len(points),
            "points": [{k: v for k, v in p.items() if k != "indices"} for p in points]}


def format_results(results, defaults: dict) -> str:
    """The search as a table: per law its pick, the shipped default's CCT beside it, and the sensitivity."""
    header = (f"{'law':>16} {'CCT (s)':>8} {'default':>8} {'worst nbr':>9} {'near':>5} {'ok':>5}  pick")
    lines = [header, "-" * (len(header) + 40)]
    for result in results:
        name, pick = result["law"], result["pick"]
        ok = f"{result['qualifying']}/{result['candidates']}"
        if pick is None:
            lines.append(f"{name:>16} {'-':>8} {defaults[name]:>8.4f} {'-':>9} {'-':>5} {ok:>5}  none settled")
            continue
        worst = result["worst_neighbour_cct_s"]
        gains = ", ".join(f"{k} {v:.4g}" for k, v in pick["gains"].items())
        lines.append(f"{name:>16} {pick['cct_s']:>8.4f} {defaults[name]:>8.4f} "
                     f"{'-' if worst is None else format(worst, '.4f'):>9} {result['share_near']:>5.0%} {ok:>5}  {gains}")
    return "\n".join(lines)

