"""Make the ANDES reference for the network plant: COI-relative rotor angles and critical clearing times.

ANDES (GPL-3) is an independent simulator: its own load flow and its own DAE
time-domain simulation (implicit trapezoid) of classical GENCLS generators with
constant-impedance loads (PQ converted to impedances in the simulation, ANDES's
default pq2z). It is not a dependency of this project: this script runs in a
separate venv and writes ``andes_reference_<case>.json`` beside it, which
tests/test_network_andes.py compares with the project's network core.

The ANDES systems are built here from the project's own case data (the MATPOWER
network and the machine CSV of each shipped case), so that the comparison tests
the simulation, not two transcriptions of the data.

Run (about 10 minutes per case on a quiet machine; cases as arguments, default all):

    python3 -m venv /tmp/andes-venv
    /tmp/andes-venv/bin/pip install andes==2.0.0 pypower==5.1.21
    PYTHONPATH=nni_plant_sim /tmp/andes-venv/bin/python tests/network_reference/make_andes_reference.py
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import andes
import numpy as np

from nni_plant_sim.cases import CASES, shipped_text, read_machines, read_matpower

#: Faults compared: (case, fault bus, fault reactance pu, tripped branch (from, to, circuit) or None,
#: clearing time of the reference trajectory s, upper end of the CCT search s).
FAULTS = (
    ("kundur_two_area", 7, 1e-4, (7, 8, 1), 0.1, 1.0),
    ("kundur_two_area", 9, 1e-4, None, 0.1, 1.0),
    ("ieee39", 16, 1e-4, None, 0.1, 0.6),
    ("ieee39", 26, 1e-4, (26, 29, 1), 0.05, 0.6),
)
FAULT_START_S = 0.5
AFTER_FAULT_S = 5.0
STEP_S = 1e-3


def case_data(name: str):
    """MATPOWER dict and machine records of a shipped case."""
    source, machines_file, f0 = CASES[name]
    if source.startswith("pypower:"):
        from pypower import api

        ppc = getattr(api, source.split(":", 1)[1])()
    else:
        ppc = read_matpower(shipped_text(source))
    return ppc, read_machines(shipped_text(machines_file)), f0


def build(name: str, bus: int, xf: float, trip, clearing_s: float) -> andes.System:
    """An ANDES system of the case with one fault, set up and load flow solved."""
    ppc, machines, f0 = case_data(name)
    base = float(ppc["baseMVA"])
    ss = andes.System()
    if ss.config.freq != f0:
        raise RuntimeError(f"ANDES runs at {ss.config.freq} Hz, the case at {f0} Hz")
    kv = {}
    for row in ppc["bus"]:
        number, kind, pd, qd, gs, bs, vm, va, base_kv = int(row[0]), int(row[1]), *row[2:6], *row[7:10]
        kv[number] = base_kv
        ss.add("Bus", {"idx": number, "name": f"B{number}", "Vn": base_kv, "v0": vm, "a0": math.radians(va)})
        if pd or qd:
            ss.add("PQ", {"idx": f"L{number}", "bus": number, "Vn": base_kv, "p0": pd / base, "q0": qd / base})
        if gs or bs:
            ss.add("Shunt", {"idx": f"S{number}", "bus": number, "Vn": base_kv, "Sn": base,
                             "g": gs / base, "b": bs / base})
    circuits = {}
    trip_idx = None
    for k, row in enumerate(ppc["branch"]):
        f, t, r, x, b, ratio, shift, status = int(row[0]), int(row[1]), row[2], row[3], row[4], row[8], row[9], row[10]
        if status <= 0:
            continue
        key = frozenset((f, t))
        circuits[key] = circuits.get(key, 0) + 1
        idx = f"Line_{k}"
        if trip is not None and frozenset(trip[:2]) == key and circuits[key] == trip[2]:
            trip_idx = idx
        ss.add("Line", {"idx": idx, "bus1": f, "bus2": t, "r": r, "x": x, "b": b, "Sn": base,
                        "Vn1": kv[f], "Vn2": kv[t], "trans": int(ratio != 0), "tap": ratio if ratio else 1.0,
                        "phi": math.radians(shift)})
    for n, (row, machine) in enumerate(zip(ppc["gen"], machines)):
        number = int(row[0])
        slack = int(ppc["bus"][ppc["bus"][:, 0] == number][0, 1]) == 3
        gen = {"idx": f"PV{n}", "bus": number, "Vn": kv[number], "Sn": machine.mbase_mva, "p0": row[1] / base,
               "q0": row[2] / base, "v0": row[5], "qmax": 99.0, "qmin": -99.0, "pmax": 99.0, "pmin": -99.0}
        if slack:
            gen["a0"] = math.radians(float(ppc["bus"][ppc["bus"][:, 0] == number][0, 8]))
        ss.add("Slack" if slack else "PV", gen)
        ss.add("GENCLS", {"idx": f"G{n}", "bus": number, "gen": f"PV{n}", "Vn": kv[number],
                          "Sn": machine.mbase_mva, "fn": f0, "M": 2.0 * machine.inertia_h_s,
                          "D": machine.damping_pu, "ra": machine.ra_pu, "xd1": machine.xd_prime_pu})
    ss.add("Fault", {"idx": "F1", "bus": bus, "tf": FAULT_START_S, "tc": FAULT_START_S + clearing_s, "xf": xf,
                     "rf": 0.0})
    if trip is not None:
        ss.add("Toggle", {"idx": "T1", "model": "Line", "dev": trip_idx, "t": FAULT_START_S + clearing_s})
    ss.setup()
    ss.PFlow.config.tol = 1e-11
    ss.PFlow.run()
    if not ss.PFlow.converged:
        raise RuntimeError(f"ANDES load flow of {name} did not converge")
    return ss


def simulate(name, bus, xf, trip, clearing_s):
    """(times since the fault, rotor angles (T, N), inertias M) of one ANDES run.

    A run that ANDES ends early (its Newton iterations fail as the machines
    separate) ends before ``AFTER_FAULT_S``: see :func:`stays_in_step`.
    """
    ss = build(name, bus, xf, trip, clearing_s)
    ss.TDS.config.tf = FAULT_START_S + AFTER_FAULT_S
    ss.TDS.config.tstep = STEP_S
    ss.TDS.config.fixt = 1
    ss.TDS.config.shrinkt = 0
    ss.TDS.config.criteria = 0
    ss.TDS.config.no_tqdm = 1
    ss.TDS.run()
    t = np.asarray(ss.dae.ts.t)
    delta = np.asarray(ss.dae.ts.x)[:, ss.GENCLS.delta.a]
    return t - FAULT_START_S, delta, np.asarray(ss.GENCLS.M.v) * np.asarray(ss.GENCLS.Sn.v)


def stays_in_step(t: np.ndarray, delta: np.ndarray) -> bool:
    """No pair of generators more than 180 degrees apart (ANDES's own ddelta criterion) over the whole run.

    A run ANDES could not finish counts as not staying in step, and says so.
    """
    in_step = bool(np.all(delta.max(axis=1) - delta.min(axis=1) <= math.pi))
    if in_step and t[-1] < AFTER_FAULT_S - 1e-6:
        print(f"  ANDES stopped at {t[-1]:.3f} s before any pair passed 180 degrees: counted as lost",
              file=sys.stderr)
        return False
    return in_step


def critical_clearing_time(name, bus, xf, trip, high_s):
    """Bisection on a 1 ms grid; returns (CCT s or None, [[clearing time s, stays in step], ...] visited).

    Plain bisection assumes that stability is monotone in the clearing time; it
    need not be (IEEE 39 bus 16: 154-167 ms lose synchronism, 168 ms holds), so
    the visited clearing times and ANDES's verdict at each are kept: the test
    checks the project's verdict at every one of them, which pins the CCT this
    bisection finds whatever the monotonicity.
    """
    lo, hi = 0, int(round(high_s / 1e-3)) + 1
    visited = []
    while hi - lo > 1:
        mid = (lo + hi) // 2
        t, delta, _ = simulate(name, bus, xf, trip, mid * 1e-3)
        in_step = stays_in_step(t, delta)
        visited.append([mid * 1e-3, in_step])
        if in_step:
            lo = mid
        else:
            hi = mid
        print(f"  {name} bus {bus}: bracket [{lo}, {hi}] ms", file=sys.stderr)
    return (lo * 1e-3 if lo else None), visited


def main(cases) -> int:
    """Write andes_reference_<case>.json for each case named (all shipped cases by default)."""
    andes.config_logger(stream_level=40)
    for case in cases or sorted({fault[0] for fault in FAULTS}):
        write_reference(case)
    return 0


def write_reference(case: str) -> None:
    """The reference of one case: its faults' trajectories and CCTs."""
    out = {"generator": f"andes {andes.__version__}, GENCLS, trapezoid, fixed step {STEP_S} s, pq2z",
           "fault_start_s": FAULT_START_S, "faults": []}
    for name, bus, xf, trip, clearing_s, high_s in (fault for fault in FAULTS if fault[0] == case):
        t, delta, m = simulate(name, bus, xf, trip, clearing_s)
        if not stays_in_step(t, delta):
            raise RuntimeError(f"{name} bus {bus}: the reference run at {clearing_s} s is not in step")
        coi = delta @ m / m.sum()
        grid = np.arange(int(round(AFTER_FAULT_S / 0.01)) + 1) * 0.01
        relative = np.column_stack([np.interp(grid, t, column) for column in (delta - coi[:, None]).T])
        out["faults"].append({
            "case": name, "bus": bus, "fault_reactance_pu": xf, "trip": trip, "clearing_time_s": clearing_s,
            "t_s": grid.round(9).tolist(), "coi_angles_rad": relative.tolist(),
        })
        cct, visited = critical_clearing_time(name, bus, xf, trip, high_s)
        out["faults"][-1].update({"cct_s": cct, "cct_search_high_s": high_s, "cct_visited": visited})
        print(f"{name} bus {bus}: cct {cct}", file=sys.stderr)
    path = Path(__file__).with_name(f"andes_reference_{case}.json")
    path.write_text(json.dumps(out) + "\n", encoding="utf-8")
    print(f"wrote {path}")


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
