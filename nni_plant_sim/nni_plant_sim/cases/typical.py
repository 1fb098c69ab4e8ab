"""Classical-machine data from a documented rule, for cases that publish no dynamic data (IEEE 118, IEEE 300).

MATPOWER's case118 and case300 (as pypower ships them) hold the network, the
loads and the dispatch, but no machine data: their ``mbase`` is the 100 MVA
placeholder of every row. The machine files ``ieee118_machines.csv`` and
``ieee300_machines.csv`` are made by :func:`typical_machines` from each
generator's active power limit and typical values of large steam
turbo-generators; they are **typical, not the utility's** data:

- rating ``S_n = PMAX / 0.85`` MVA (``PMAX`` of the gen table; 0.85 is the
  typical rated power factor of a large turbo-generator);
- inertia ``H = 4.0 s`` on the rating: inside the 2.5 to 6.0 s that P. Kundur,
  *Power System Stability and Control* (McGraw-Hill 1994), section 3.9,
  Table 3.2, gives as typical for thermal units at 3600 r/min;
- transient reactance ``x'_d = 0.25 pu`` on the rating: inside the 0.15 to
  0.4 pu of round-rotor units in the same book's Table 4.2 (typical values of
  standard parameters);
- ``Ra = 0``, ``D = 0`` (as the IEEE 39 machine file: classical, undamped).

So each unit's inertia (MW s) and its reactance on the system base follow its
size: ``M_i`` grows with ``S_n``, ``x'_d`` on 100 MVA falls as ``0.25 * 100 /
S_n``. Run ``python -m nni_plant_sim.cases.typical case118 > ieee118_machines.csv``
to remake a file; ``tests/test_screening_cases.py`` checks the shipped files
equal this rule's output. Pure python: no ROS import.
"""

from __future__ import annotations

import sys

#: The rule's typical values (see the module docstring for their source).
RATED_POWER_FACTOR = 0.85
INERTIA_H_S = 4.0
XD_PRIME_PU = 0.25


def typical_machines(ppc: dict) -> list[tuple]:
    """One ``(bus, mbase_mva, inertia_h_s, xd_prime_pu, ra_pu, damping_pu)`` per in-service generator, in gen order."""
    rows = []
    for gen in ppc["gen"]:
        if gen[7] <= 0:  # GEN_STATUS
            continue
        rows.append((int(gen[0]), round(float(gen[8]) / RATED_POWER_FACTOR, 3), INERTIA_H_S, XD_PRIME_PU, 0.0, 0.0))
    return rows


def machine_file_text(case_name: str, title: str) -> str:
    """The machine CSV of pypower's ``case_name``, its provenance in its header."""
    from pypower import api

    lines = [
        f"# Classical-model machine data of the {title}, pu on each machine's rating: TYPICAL values from a",
        "# documented rule, not the utility's data (the MATPOWER case publishes none: its mbase is 100 MVA",
        "# in every row). Rule (nni_plant_sim/cases/typical.py): rating S_n = PMAX / 0.85 MVA (PMAX of the",
        f"# case's gen table; 0.85 a typical rated power factor); H = {INERTIA_H_S:g} s and x'_d = {XD_PRIME_PU:g} pu on "
        "the rating,",
        "# typical of large steam turbo-generators (P. Kundur, Power System Stability and Control, McGraw-Hill",
        "# 1994: Table 3.2, H 2.5-6.0 s for thermal units at 3600 r/min; Table 4.2, x'_d 0.15-0.4 pu for round",
        "# rotors); Ra = 0, D = 0. The network (bus, branch, load and dispatch data) is MATPOWER's",
        f"# {case_name} as shipped by pypower. One row per generator, in the order of the case's gen table.",
        "bus,mbase_mva,inertia_h_s,xd_prime_pu,ra_pu,damping_pu",
    ]
    for row in typical_machines(getattr(api, case_name)()):
        lines.append(",".join(f"{value:g}" for value in row))
    return "\n".join(lines) + "\n"


#: The cases built with this rule: pypower case -> the title in the file's header.
TITLES = {"case118": "IEEE 118-bus system", "case300": "IEEE 300-bus system"}

if __name__ == "__main__":
    sys.stdout.write(machine_file_text(sys.argv[1], TITLES[sys.argv[1]]))
