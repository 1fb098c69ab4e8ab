"""``nni-simulate --compare-laws``: every battery law on the same SMIB, battery limit and PMU rate.

Per law and battery limit b, the sampled-data run of the scenario (the paper's
case by default) at the plant node's PMU rate: its verdict and settling time,
the battery energy it moved (integral of |P_ST| dt, pu s; MWh per 100 MVA of
rating) and its time in saturation (|demand| >= b, summed over the held
periods); and the critical clearing time of the transfer-limit fault by the
bisection of ``--cct`` (:func:`.smib_study.smib_cct`), every law through the
same code. The region-of-attraction sweep is not part of the comparison yet
(the ``--roa`` sweep is the continuous nni law's). Pure python: no ROS import.
"""

from __future__ import annotations

import math

from nni_battery_controller.laws import LAW_NAMES
from nni_battery_controller.verdicts import assess, verdict_text

#: MWh per pu s on a 100 MVA rating: 100 MW for one second is 100/3600 MWh.
MWH_PER_PU_S_100MVA = 100.0 / 3600.0


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
            "time_saturated_s": saturated if traj.ctrl.battery_limit_pu > 0 else None}


def compare(laws_by_b, simulate_run, cct_of) -> list[dict]:
    """Rows ``{law, b, run..., cct_s, cct_slips_s}`` for ``laws_by_b`` ({b: [Law, ...]}).

    ``simulate_run(law)`` runs the scenario, ``cct_of(law)`` returns a :class:`.margins.ClearingTime`.
    """
    rows = []
    for b, laws in laws_by_b.items():
        for law in laws:
            traj, scenario = simulate_run(law)
            cct = cct_of(law)
            rows.append({"law": law.name, "b": "inf" if math.isinf(b) else b, **run_summary(traj, scenario),
                         "cct_s": cct.cct_s, "cct_slips_s": cct.slips_s, "gains": law.gain_values()})
    return rows


def format_rows(rows) -> str:
    """The comparison as a fixed-width table, grouped by b."""
    def num(value, fmt):
        return "-" if value is None else fmt.format(value)

    header = (f"{'b (pu)':>7} {'law':>16} {'CCT (s)':>8} {'settle (s)':>10} {'energy (pu s)':>13} "
              f"{'saturated (s)':>13}  verdict")
    lines = [header, "-" * (len(header) + 24)]
    for row in rows:
        b = math.inf if row["b"] == "inf" else row["b"]
        cct = f"{row['cct_s']:.3f}" if row["cct_slips_s"] is not None else f">={row['cct_s']:.3f}"
        lines.append(f"{b:>7g} {row['law']:>16} {cct:>8} {num(row['settling_time_s'], '{:.3f}'):>10} "
                     f"{row['energy_pu_s']:>13.4f} {num(row['time_saturated_s'], '{:.3f}'):>13}  {row['verdict']}")
    return "\n".join(lines)


def comparison_figure(rows, title: str):
    """CCT against b, one line per law (b = inf drawn at the right edge, labelled)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    finite = sorted({row["b"] for row in rows if row["b"] != "inf"})
    edge = (max(finite) * 1.25 if finite and max(finite) > 0 else 1.0)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name in LAW_NAMES:
        mine = [row for row in rows if row["law"] == name]
        if not mine:
            continue
        xs = [edge if row["b"] == "inf" else row["b"] for row in mine]
        ax.plot(xs, [row["cct_s"] for row in mine], marker="o", label=name)
    ax.set_xlabel("battery limit b (pu; the rightmost point: unlimited)")
    ax.set_ylabel("critical clearing time (s)")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.suptitle(title)
    fig.tight_layout()
    return fig
