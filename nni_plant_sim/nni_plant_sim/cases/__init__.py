"""Test systems for the network plant, and readers for the formats users bring their own in.

A case is a MATPOWER-format network (``baseMVA``, ``bus``, ``gen``, ``branch``;
read from a MATPOWER ``.m`` file or taken from pypower) plus one classical
machine record per generator (a CSV: bus, mbase_mva, inertia_h_s, xd_prime_pu,
ra_pu, damping_pu; pu on the machine's rating, like a PSS/E GENCLS record).
Shipped:

- ``kundur_two_area``: ``kundur_two_area.m`` and ``kundur_two_area_machines.csv``,
  typed from Kundur (1994), Example 12.6; 60 Hz.
- ``ieee39``: MATPOWER's case39 from pypower with ``ieee39_machines.csv``
  (Athay et al. 1979 / Pai 1989); 60 Hz.
- ``kundur_ring_52``: synthetic, 52 generators: 13 copies of ``kundur_two_area``
  tied in a ring (:mod:`.replicated` says how); its machine file is the
  two-area system's, replicated; 60 Hz.
- ``ieee118``, ``ieee300``: MATPOWER's case118 and case300 from pypower (54 and
  69 generators) with ``ieee118_machines.csv`` / ``ieee300_machines.csv``:
  typical classical-machine data from a documented rule (:mod:`.typical`), not
  the utility's; 60 Hz.

Pure python: no ROS import.
"""

from __future__ import annotations

import csv
import hashlib
import math
import re
from importlib import resources
from pathlib import Path

import numpy as np

from nni_plant_sim.cases.replicated import ring_of_kundur
from nni_plant_sim.network import Machine, Network, network_from_case

#: Shipped cases: name -> (network source, machine file, nominal frequency Hz). A source is a shipped
#: ``.m`` file, ``pypower:<case>``, or ``kundur_ring:<copies>`` (built by :func:`.replicated.ring_of_kundur`).
CASES = {
    "kundur_two_area": ("kundur_two_area.m", "kundur_two_area_machines.csv", 60.0),
    "ieee39": ("pypower:case39", "ieee39_machines.csv", 60.0),
    "kundur_ring_52": ("kundur_ring:13", "kundur_two_area_machines.csv", 60.0),
    "ieee118": ("pypower:case118", "ieee118_machines.csv", 60.0),
    "ieee300": ("pypower:case300", "ieee300_machines.csv", 60.0),
}
#: Fault bus of a bus fault when none is given: a load bus of each shipped case (kundur_ring_52: copy 0's bus 7,
#: as the network plant node's default).
DEFAULT_FAULT_BUS = {"kundur_two_area": 7, "ieee39": 16, "kundur_ring_52": 7, "ieee118": 30, "ieee300": 9}

_MATRIX = re.compile(r"mpc\.(bus|gen|branch)\s*=\s*\[(.*?)\]\s*;", re.S)
_BASE = re.compile(r"mpc\.baseMVA\s*=\s*([0-9.eE+-]+)\s*;")


def read_matpower(text: str) -> dict:
    """The ``baseMVA``, ``bus``, ``gen`` and ``branch`` of a MATPOWER case file's text.

    Reads the numeric matrices (``%`` comments and ``;`` row ends allowed);
    other fields (gencost, bus names) are ignored since the load flow and the
    network do not use them. ValueError naming what is missing or malformed.
    """
    text = re.sub(r"%[^\n]*", "", text)
    base = _BASE.search(text)
    if base is None:
        raise ValueError("MATPOWER case: no 'mpc.baseMVA = ...;'")
    case = {"version": "2", "baseMVA": float(base.group(1))}
    for name, body in _MATRIX.findall(text):
        rows = [row.split() for row in body.replace(";", "\n").splitlines() if row.strip()]
        try:
            case[name] = np.array([[float(v) for v in row] for row in rows])
        except ValueError as error:
            raise ValueError(f"MATPOWER case: mpc.{name} is not a numeric matrix ({error})") from None
        if case[name].ndim != 2:
            raise ValueError(f"MATPOWER case: mpc.{name} rows differ in length")
    missing = [name for name in ("bus", "gen", "branch") if name not in case]
    if missing:
        raise ValueError(f"MATPOWER case: missing {', '.join('mpc.' + m for m in missing)}")
    return case


def read_machines(text: str) -> list[Machine]:
    """Machine records from CSV text (``#`` comment lines; header as in the shipped files)."""
    lines = [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    reader = csv.DictReader(lines)
    fields = ("bus", "mbase_mva", "inertia_h_s", "xd_prime_pu", "ra_pu", "damping_pu")
    if reader.fieldnames is None or any(f not in reader.fieldnames for f in fields):
        raise ValueError(f"machine file: the header must name {', '.join(fields)}")
    machines = []
    for number, row in enumerate(reader, start=1):
        try:
            values = {f: float(row[f]) for f in fields}
        except (TypeError, ValueError):
            raise ValueError(f"machine file: row {number} is not numeric: {row}") from None
        if not all(math.isfinite(v) for v in values.values()):
            raise ValueError(f"machine file: row {number} has a non-finite value")
        machines.append(Machine(bus=int(values.pop("bus")), **values))
    return machines


def shipped_text(filename: str) -> str:
    """The text of a file shipped with the cases (a .m network or a machine CSV)."""
    return resources.files(__name__).joinpath(filename).read_text(encoding="utf-8")


def case_data(case: str, machines_path: str | None = None, f0_hz: float | None = None) -> tuple:
    """``(ppc, machines, f0_hz)`` of a shipped case by name, or of a MATPOWER ``.m`` file with a machine CSV.

    What :func:`load_network` solves and reduces, and what :func:`case_digest`
    hashes. Raises ValueError with one line on a missing or malformed file.
    """
    if case in CASES:
        source, machines_file, default_f0 = CASES[case]
        machines = read_machines(shipped_text(machines_file) if machines_path is None
                                 else Path(machines_path).read_text(encoding="utf-8"))
        if source.startswith("pypower:"):
            from pypower import api

            ppc = getattr(api, source.split(":", 1)[1])()
        elif source.startswith("kundur_ring:"):
            ppc, machines = ring_of_kundur(read_matpower(shipped_text("kundur_two_area.m")), machines,
                                           int(source.split(":", 1)[1]))
        else:
            ppc = read_matpower(shipped_text(source))
        return ppc, machines, default_f0 if f0_hz is None else f0_hz
    path = Path(case)
    if not path.is_file():
        raise ValueError(f"case {case!r} is neither a shipped case ({', '.join(CASES)}) nor a MATPOWER file")
    if machines_path is None:
        raise ValueError("a MATPOWER case file needs its machine data: --machines FILE.csv")
    if f0_hz is None:
        raise ValueError("a MATPOWER case file needs its nominal frequency: --f0 HZ")
    return (read_matpower(path.read_text(encoding="utf-8")),
            read_machines(Path(machines_path).read_text(encoding="utf-8")), f0_hz)


def load_network(case: str, machines_path: str | None = None, f0_hz: float | None = None) -> Network:
    """A shipped case by name, or a MATPOWER ``.m`` file with a machine CSV, solved and reduced.

    Raises ValueError with one line on a missing or malformed file.
    """
    return network_from_case(*case_data(case, machines_path, f0_hz))


def case_digest(ppc: dict, machines, f0_hz: float) -> str:
    """SHA-256 (hex) of what a case is made of: its base, bus, gen and branch tables, machine records and f0.

    Two cases with the same digest give the same network; a screen's output
    folder records it so that ``--resume`` refuses another case's folder.
    """
    digest = hashlib.sha256()
    digest.update(repr(float(ppc["baseMVA"])).encode())
    for name in ("bus", "gen", "branch"):
        digest.update(name.encode())
        digest.update(np.ascontiguousarray(ppc[name], dtype=float).tobytes())
    for machine in machines:
        digest.update(repr(machine).encode())
    digest.update(repr(float(f0_hz)).encode())
    return digest.hexdigest()
