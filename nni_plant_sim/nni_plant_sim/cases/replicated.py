"""A synthetic network of many generators: copies of Kundur's two-area system tied in a ring.

Built, not shipped as data, so that its size is a parameter and its every
number traces back to the published two-area case (``kundur_two_area.m`` and
``kundur_two_area_machines.csv``, Kundur 1994, Example 12.6). What it is for:
scaling the distributed loop (one controller per generator) to 50 and more
generators; it is not a published test system.

How :func:`ring_of_kundur` builds it from ``copies`` copies (k = 0 .. copies-1):

- copy k is the two-area system with every bus number b renumbered
  ``b + 100 k`` (copy 0 keeps Kundur's numbers 1..11, so bus 7 is its first
  load bus as in the two-area case); its four generators, in the order of the
  gen table, are those at buses ``1..4 + 100 k`` with Kundur's machine data;
- one slack for the whole network: copy 0's bus 3 (Kundur's swing machine);
  in the other copies bus 3 is a PV bus at Kundur's 719 MW;
- copy k's bus ``9 + 100 k`` (area 2's load bus) is tied to copy k+1's bus
  ``7 + 100 (k+1)`` (area 1's load bus), the last copy to copy 0, by one
  circuit of the 7-8 corridor (110 km: r = 0.011, x = 0.11, b = 0.1925 pu on
  100 MVA), a ring of ``copies`` tie lines appended after the copies' branches;
- then, as for every case, the load flow (pypower) and the Kron reduction
  (:func:`nni_plant_sim.network.network_from_case`).

The copies are alike, so the load flow finds each copy's angles alike up to
the slack's share; the ties carry area 1 to area 2 flow of the neighbouring
copy beside each copy's own corridor. Pure python: no ROS import.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

#: Bus numbers of copy k are Kundur's plus this times k.
BUS_OFFSET = 100
#: The two buses a tie joins: area 2's load bus of one copy to area 1's load bus of the next.
TIE_FROM_BUS, TIE_TO_BUS = 9, 7
#: The branch a tie copies: the first 7-8 circuit of Kundur's branch table (110 km).
TIE_TEMPLATE_ENDS = (7, 8)
#: MATPOWER bus types.
_PV, _SLACK = 2, 3


def ring_of_kundur(two_area: dict, machines, copies: int) -> tuple[dict, list]:
    """The MATPOWER-format case and machine records of ``copies`` two-area systems tied in a ring.

    ``two_area`` is Kundur's case (``read_matpower`` of ``kundur_two_area.m``),
    ``machines`` its four machine records; ``copies`` >= 2. Returns
    ``(ppc, machines)`` for :func:`nni_plant_sim.network.network_from_case`.
    """
    if copies < 2:
        raise ValueError(f"a ring needs at least 2 copies, got {copies}")
    buses, gens, branches, records = [], [], [], []
    for k in range(copies):
        offset = BUS_OFFSET * k
        bus = two_area["bus"].copy()
        bus[:, 0] += offset
        if k > 0:
            bus[bus[:, 1] == _SLACK, 1] = _PV
        gen = two_area["gen"].copy()
        gen[:, 0] += offset
        branch = two_area["branch"].copy()
        branch[:, :2] += offset
        buses.append(bus)
        gens.append(gen)
        branches.append(branch)
        records += [replace(machine, bus=machine.bus + offset) for machine in machines]
    ends = two_area["branch"][:, :2]
    template = two_area["branch"][np.flatnonzero((ends[:, 0] == TIE_TEMPLATE_ENDS[0])
                                                 & (ends[:, 1] == TIE_TEMPLATE_ENDS[1]))[0]]
    ties = np.tile(template, (copies, 1))
    ties[:, 0] = TIE_FROM_BUS + BUS_OFFSET * np.arange(copies)
    ties[:, 1] = TIE_TO_BUS + BUS_OFFSET * ((np.arange(copies) + 1) % copies)
    ppc = {"version": "2", "baseMVA": two_area["baseMVA"], "bus": np.vstack(buses), "gen": np.vstack(gens),
           "branch": np.vstack(branches + [ties])}
    return ppc, records
