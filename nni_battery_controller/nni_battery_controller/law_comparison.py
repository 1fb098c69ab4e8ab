"""``nni-simulate --compare-laws``: every battery law on the same plant (the SMIB or a network), battery limit
and PMU rate.

Per law and battery limit b, the sampled-data run of the scenario (the paper's
case by default) at the plant node's PMU rate: its verdict and settling time,
the battery energy it moved (integral of |P_ST| dt, pu s; MWh per 100 MVA of
rating) and its time in saturation (|demand| >= b, summed over the held
periods); and the critical clearing time of the transfer-limit fault by the
bisection of ``--cct`` (:func:`.smib_study.smib_cct`), every law through the
same code. The region-of-attraction sweep is not part of the comparison yet
(the ``--roa`` sweep is the continuous nni law's).

A network (``--case``): per angle reference, law and b (the same at every generator), the sampled run of the
bus fault (its verdict, the last generator's settling time, the energy every battery moved in MWh, the longest
time a battery spent saturated) and the fault's CCT by ``--cct``'s vectorised bisection
(:func:`.network_sim.critical_clearing_times`). Pure python: no ROS import.
"""

from __future__ import annotations

import math

import numpy as np

from nni_battery_controller.laws import LAW_NAMES
from nni_battery_controller.network_sim import network_verdict
from nni_battery_controller.verdicts import assess, number_or_dash, verdict_text

#: MWh per pu s on a 100 MVA rating: 100 MW for one second is 100/3600 MWh.
MWH_PER_PU_S_100MVA = 100.0 / 3600.0
#: A SMIB row's region-of-attraction areas (rad * rad/s), from :meth:`.roa.Basin.summary`'s: in synchronism, and
#: returned.
ROA_KEYS = {"roa_synchronism_area_rad2_per_s": "synchronism_area_rad2_per_s",
            "roa_returns_area_rad2_per_s": "returns_area_rad2_per_s"}


def run_summary(traj, scenario) -> dict:
    """One law's run: the verdict, the settling time, energy moved and time in saturation."""
    outcome = assess(traj, scenario=scenario).to_json()
    period = float(traj.t_s[1] - traj.t_s[0])
    held = traj.battery_power_pu[:-1]  # each held over one period; the last sample holds nothing
    energy = float(sum(abs(p) for p in held) * period)
    saturated = float(sum(bool(s) for s in traj.saturated[:-1]) * period)
    return {"verdict": verdict_text(outcome), "in_synchronism": outcome["in_synchronism"],
            "settled": outcome["settled"], "settling_time_s": outcome["settling_time_s"],
            "energy_pu_s": energy, "energy_mwh_per_100mva": energy * MWH_PER_PU_S_100MVA,
            "time_saturated_s": saturated if traj.ctrl.battery_limit_pu > 0 else None,
            **({} if traj.charge_pu_s is None else {"battery_empty_at_s": traj.empty_at_s})}


def basin_entries(basin) -> dict:
    """A row's region-of-attraction entries of a :class:`.roa.Basin` (:func:`.law_roa.sampled_basin`'s)."""
    summary = basin.summary()
    return {key: summary[basin_key] for key, basin_key in ROA_KEYS.items()}


def compare(laws_by_b, simulate_run, cct_of, roa_of=None) -> list[dict]:
    """Rows ``{law, b, run..., cct_s, cct_slips_s, roa_...}`` for ``laws_by_b`` ({b: [Law, ...]}).

    ``simulate_run(law)`` runs the scenario, ``cct_of(law)`` returns a :class:`.margins.ClearingTime`,
    ``roa_of(law)`` the region-of-attraction areas (:func:`basin_entries`; None: not swept, the areas None).
    """
    rows = []
    for b, laws in laws_by_b.items():
        for law in laws:
            traj, scenario = simulate_run(law)
            cct = cct_of(law)
            roa = dict.fromkeys(ROA_KEYS) if roa_of is None else roa_of(law)
            rows.append({"law": law.name, "b": "inf" if math.isinf(b) else b, **run_summary(traj, scenario),
                         "cct_s": cct.cct_s, "cct_slips_s": cct.slips_s, **roa, "gains": law.gain_values()})
    return rows


def network_run_summary(traj, run: int, outcome) -> dict:
    """Run ``run`` of a network trajectory with its :class:`.network_sim.NetworkOutcome`: the verdict, the
    settling time (of the last generator to settle), the energy each battery moved and the longest saturation;
    a run that lost synchronism up to its pole slip (past it the machines, and an unlimited battery chasing
    them, run away: the energy of a diverging run means nothing)."""
    net, t = traj.net, traj.t_s
    period = float(t[1] - t[0])
    end = t.size - 1 if outcome.in_synchronism else int(np.searchsorted(t, outcome.pole_slip_s))
    held = np.abs(traj.battery_power_pu[:end, :, run])  # system base, each held one period
    energy_mwh = held.sum(axis=0) * period * net.base_mva / 3600.0
    saturated = traj.saturated[:end, :, run].sum(axis=0) * period
    settle = max(g.settling_time_s for g in outcome.generators) if outcome.settled else None
    return {"verdict": network_verdict(outcome), "in_synchronism": outcome.in_synchronism,
            "settled": outcome.settled, "settling_time_s": settle, "energy_mwh": float(energy_mwh.sum()),
            "energy_mwh_per_generator": [float(e) for e in energy_mwh],
            "time_saturated_s": float(saturated.max()) if np.any(traj.limits_pu[:, run] > 0) else None}


def compare_network(limits, laws, simulate_runs, ccts_of) -> list[dict]:
    """Rows ``{reference, law, b, run..., cct_s, cct_bracket_s, at_search_limit, gains}`` for ``laws``
    ({reference: [NetworkLaw, ...]}) at every b of ``limits``: ``simulate_runs(law)`` returns the trajectory
    and outcomes of every b (one vectorised run), ``ccts_of(law)`` :func:`.network_sim.critical_clearing_times`'
    ``(cct or None, bracket, at_limit)`` per b."""
    rows = []
    for reference, mine in laws.items():
        by_b = {}
        for law in mine:
            traj, outcomes = simulate_runs(law)
            for r, (b, (cct, bracket, at_limit)) in enumerate(zip(limits, ccts_of(law))):
                by_b.setdefault(r, []).append({
                    "reference": reference, "law": law.name, "b": "inf" if math.isinf(b) else b,
                    **network_run_summary(traj, r, outcomes[r]), "cct_s": cct, "cct_bracket_s": list(bracket),
                    "at_search_limit": bool(at_limit), "gains": law.laws()[0].gain_values()})
        rows += [row for r in sorted(by_b) for row in by_b[r]]
    return rows


def format_network_rows(rows) -> str:
    """The network comparison as a fixed-width table, grouped by reference and b."""
    header = (f"{'b (pu)':>7} {'reference':>9} {'law':>16} {'CCT (s)':>8} {'settle (s)':>10} {'energy (MWh)':>12} "
              f"{'saturated (s)':>13}  verdict")
    lines = [header, "-" * (len(header) + 24)]
    for row in rows:
        b = math.inf if row["b"] == "inf" else row["b"]
        cct = "none" if row["cct_s"] is None else (f">={row['cct_s']:.3f}" if row["at_search_limit"]
                                                   else f"{row['cct_s']:.3f}")
        lines.append(f"{b:>7g} {row['reference']:>9} {row['law']:>16} {cct:>8} "
                     f"{number_or_dash(row['settling_time_s'], '{:.3f}'):>10} {row['energy_mwh']:>12.3f} "
                     f"{number_or_dash(row['time_saturated_s'], '{:.3f}'):>13}  {row['verdict']}")
    return "\n".join(lines)


def format_rows(rows) -> str:
    """The comparison as a fixed-width table, grouped by b."""
    empties = bool(rows) and "battery_empty_at_s" in rows[0]
    header = (f"{'b (pu)':>7} {'law':>16} {'CCT (s)':>8} {'ROA sync':>8} {'ROA back':>8} {'settle (s)':>10} "
              f"{'energy (pu s)':>13} {'saturated (s)':>13}" + (f" {'empty at (s)':>12}" if empties else "")
              + "  verdict")
    lines = [header, "-" * (len(header) + 24)]
    for row in rows:
        b = math.inf if row["b"] == "inf" else row["b"]
        cct = f"{row['cct_s']:.3f}" if row["cct_slips_s"] is not None else f">={row['cct_s']:.3f}"
        empty = f" {number_or_dash(row['battery_empty_at_s'], '{:.3f}'):>12}" if empties else ""
        areas = " ".join(f"{number_or_dash(row[key], '{:.2f}'):>8}" for key in ROA_KEYS)
        settle, saturated = (number_or_dash(row[key], "{:.3f}") for key in ("settling_time_s", "time_saturated_s"))
        lines.append(f"{b:>7g} {row['law']:>16} {cct:>8} {areas} {settle:>10} {row['energy_pu_s']:>13.4f} "
                     f"{saturated:>13}{empty}  {row['verdict']}")
    return "\n".join(lines)


def comparison_figure(rows, title: str):
    """CCT against b, one line per law and (a network's rows) angle reference (b = inf drawn at the right edge);
    beside it, where the rows have them, the region-of-attraction areas against b per law (in synchronism solid,
    returned dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    finite = sorted({row["b"] for row in rows if row["b"] != "inf"})
    edge = (max(finite) * 1.25 if finite and max(finite) > 0 else 1.0)
    references = list(dict.fromkeys(row.get("reference") for row in rows))
    sync_key, back_key = ROA_KEYS
    swept = any(row.get(sync_key) is not None for row in rows)
    fig, axes = plt.subplots(1, 2 if swept else 1, figsize=(12, 4.5) if swept else (7, 4.5), squeeze=False)
    ax = axes[0][0]

    def b_axis(row) -> float:
        return edge if row["b"] == "inf" else row["b"]

    for reference in references:
        for name in LAW_NAMES:
            mine = [row for row in rows if row["law"] == name and row.get("reference") == reference]
            if not mine:
                continue
            ax.plot([b_axis(row) for row in mine], [math.nan if row["cct_s"] is None else row["cct_s"] for row in mine],
                    marker="o", linestyle="-" if reference == references[0] else "--",
                    color=f"C{LAW_NAMES.index(name)}", label=name if len(references) == 1 else f"{name}, {reference}")
    ax.set_ylabel("critical clearing time (s)" + (", at least where at the search limit"
                                                  if any(row.get("at_search_limit") for row in rows) else ""))
    if swept:
        roa = axes[0][1]
        for name in LAW_NAMES:
            mine = [row for row in rows if row["law"] == name]
            for key, style, what in ((sync_key, "-", "in sync"), (back_key, "--", "returned")):
                roa.plot([b_axis(row) for row in mine], [row[key] for row in mine], marker="o", linestyle=style,
                         color=f"C{LAW_NAMES.index(name)}", label=f"{name}, {what}")
        roa.set_ylabel("region of attraction (rad x rad/s)")
        roa.legend(fontsize="small", ncol=2)
    for axis in axes[0]:
        axis.set_xlabel("battery limit b (pu; the rightmost point: unlimited)")
        axis.grid(True, alpha=0.3)
    ax.legend()
    fig.suptitle(title)
    fig.tight_layout()
    return fig
