"""Dynamic security screening: every contingency of a case, its critical clearing time per battery limit and law.

A **contingency** is a three-phase fault that protection clears:

- ``bus:B``: a fault at bus B, cleared with nothing tripped (the pre-fault
  network returns);
- ``line:F-T:C@E``: a fault at end E (F or T) of circuit C between buses F and
  T (circuits counted in case order, 1 first), cleared by tripping that line.
  The fault is modelled **at the bus of that end**: the classical model has no
  point along a line, and a bolted fault just beyond the breaker holds the bus
  at zero voltage as a fault at the bus does; the two ends differ in which bus
  is held at zero while the line is still in.

A line whose trip islands the network (cuts some buses off the rest: a
radial load, or a generator's step-up transformer) is **skipped**, with the
reason, never screened against a network that is not what the trip leaves.

For each contingency, each battery limit b (pu of each machine's rating) and
each law, :func:`screen_chunk` finds the critical clearing time with
:func:`nni_battery_controller.network_sim.critical_clearing_times` (the
method and tolerance of ``nni-simulate --case --cct``: every b of a
contingency in one vectorised bisection), the verdict of one run cleared at a
stated clearing time, and the weakest generator of that run (the one whose
angle relative to the centre of inertia swings farthest from its pre-fault
value). Pure python (numpy): no ROS import, no dask (the engine that
distributes :func:`screen_chunk` is :mod:`nni_battery_controller.screen_engine`).
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import asdict, dataclass

import numpy as np

from nni_battery_controller.law import ControllerParams
from nni_battery_controller.laws import LAW_NAMES, law_from_parameters
from nni_msgs_adapter.ros.defaults import controller_defaults
from nni_battery_controller.network_sim import (
    POLE_SLIP_RAD,
    NetworkLaw,
    angle_spread,
    critical_clearing_times,
    simulate_network,
)
from nni_plant_sim.cases import CASES, case_data, case_digest, read_machines, read_matpower
from nni_plant_sim.network import network_from_case
from nni_plant_sim.network_scenarios import BusFault

#: The contingency kinds, as ``--contingencies`` names them.
KINDS = ("bus", "line")
#: The laws a screen runs (:func:`screen_law` is where one is chosen).
AVAILABLE_LAWS = LAW_NAMES
#: A loss of synchronism within this long after clearing is a first-swing loss, s.
FIRST_SWING_S = 1.0
#: The verdict words of the run cleared at the stated clearing time.
IN_SYNCHRONISM, FIRST_SWING_LOSS, LATER_LOSS = "in synchronism", "first-swing loss", "later-swing loss"


@dataclass(frozen=True)
class Contingency:
    """One fault and what clearing it trips: ``branch`` (index in the case's in-service branches) or None."""

    kind: str
    bus: int
    branch: int | None = None
    line: tuple | None = None  # (from bus, to bus, circuit) of the tripped line

    @property
    def name(self) -> str:
        """``bus:16`` or ``line:26-29:1@26``."""
        if self.kind == "bus":
            return f"bus:{self.bus}"
        return f"line:{self.line[0]}-{self.line[1]}:{self.line[2]}@{self.bus}"


def _branch_lines(net) -> list[tuple]:
    """(from bus, to bus, circuit) of every in-service branch, in case order."""
    model = net.bus_model
    seen, lines = {}, []
    for f, t in model.branch_ends:
        key = frozenset((int(f), int(t)))
        seen[key] = seen.get(key, 0) + 1
        lines.append((int(model.bus_numbers[f]), int(model.bus_numbers[t]), seen[key]))
    return lines


def enumerate_contingencies(net, kinds=KINDS) -> list[Contingency]:
    """Every bus fault (case order of the buses), then every line-end fault (branch order, from end first)."""
    found = []
    if "bus" in kinds:
        found += [Contingency("bus", int(bus)) for bus in net.bus_model.bus_numbers]
    if "line" in kinds:
        for index, line in enumerate(_branch_lines(net)):
            found += [Contingency("line", line[0], index, line), Contingency("line", line[1], index, line)]
    return found


def parse_contingency(net, text: str) -> Contingency:
    """The contingency named ``bus:B`` or ``line:F-T[:C]@E`` (circuit 1 when not given); ValueError naming it."""
    word = text.strip()
    kind, _, rest = word.partition(":")
    try:
        if kind == "bus" and rest.isdigit():
            net.bus_model.bus_index(int(rest))
            return Contingency("bus", int(rest))
        if kind == "line" and "@" in rest:
            ends, end = rest.split("@", 1)
            pair, _, circuit = ends.partition(":")
            from_bus, to_bus = (int(bus) for bus in pair.split("-"))
            circuit_number = int(circuit) if circuit else 1
            index = net.bus_model.branch_index(from_bus, to_bus, circuit_number)
            line = _branch_lines(net)[index]
            if int(end) not in line[:2]:
                raise ValueError(f"bus {end} is not an end of the line {from_bus}-{to_bus}")
            return Contingency("line", int(end), index, line)
    except ValueError as error:
        raise ValueError(f"contingency {word!r}: {error}") from None
    raise ValueError(f"contingency {word!r}: expected bus:B or line:F-T[:C]@E (E the faulted end, F or T)")


def islanding_reason(net, contingency: Contingency) -> str | None:
    """Why the contingency's trip cannot be screened (it islands the network), or None when it can."""
    if contingency.branch is None:
        return None
    model = net.bus_model
    n = len(model.bus_numbers)
    parent = list(range(n))

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for k, (f, t) in enumerate(model.branch_ends):
        if k != contingency.branch:
            parent[root(int(f))] = root(int(t))
    roots = [root(i) for i in range(n)]
    if len(set(roots)) == 1:
        return None
    main = max(set(roots), key=roots.count)
    cut = [i for i in range(n) if roots[i] != main]
    buses = ", ".join(str(int(model.bus_numbers[i])) for i in cut)
    stranded = [net.names[g] for g, bus in enumerate(model.gen_index) if roots[bus] != main]
    what = f" with generator{'s' if len(stranded) > 1 else ''} {', '.join(stranded)}" if stranded else \
        " (no generator)"
    return f"the trip of {contingency.line[0]}-{contingency.line[1]} islands the network: bus" \
           f"{'es' if len(cut) > 1 else ''} {buses}{what} cut off"


@dataclass(frozen=True)
class CaseSpec:
    """What a worker needs to build the case's network: a shipped case's name, or a MATPOWER file's text.

    Texts travel with the task, so that a worker on another host needs no file of the user's.
    """

    case: str
    matpower_text: str | None = None
    machines_text: str | None = None
    f0_hz: float | None = None

    @classmethod
    def of(cls, case: str, machines_path=None, f0_hz=None) -> "CaseSpec":
        """From the command line's ``--case``, ``--machines``, ``--f0`` (files read here; ValueError as load_network)."""
        from pathlib import Path

        case_data(case, machines_path, f0_hz)  # the same checks and errors as load_network
        machines = None if machines_path is None else Path(machines_path).read_text(encoding="utf-8")
        matpower = None if case in CASES else Path(case).read_text(encoding="utf-8")
        return cls(case, matpower, machines, f0_hz)

    def data(self) -> tuple:
        """``(ppc, machines, f0_hz)`` (:func:`nni_plant_sim.cases.case_data`)."""
        if self.case in CASES:
            ppc, machines, f0 = case_data(self.case, None, self.f0_hz)
        else:
            ppc, machines, f0 = read_matpower(self.matpower_text), None, self.f0_hz
        if self.machines_text is not None:
            machines = read_machines(self.machines_text)
        return ppc, machines, f0

    def digest(self) -> str:
        """The case's identity (:func:`nni_plant_sim.cases.case_digest`)."""
        return case_digest(*self.data())


@functools.lru_cache(maxsize=4)
def network_of(spec: CaseSpec):
    """The solved, reduced network of ``spec``, built once per process (a worker keeps it between tasks)."""
    return network_from_case(*spec.data())


@dataclass(frozen=True)
class ScreenSettings:
    """Everything a screen's numbers depend on besides the case (stored in its output folder's manifest)."""

    limits_pu: tuple  # battery limits b, pu of each machine's rating (inf allowed)
    laws: tuple
    reference: str = "pmu"
    tau_s: tuple = (0.1,)
    gain_k: tuple = (1.0,)
    gain_l: tuple = (1.1,)
    alpha: tuple = (1.0,)
    duration_s: float = 10.0
    rate_hz: float = 50.0
    cct_max_s: float = 1.0
    resolution_s: float = 1e-3
    points: int = 31
    clearing_time_s: float = 0.1  # the stated clearing time of each row's verdict
    fault_impedance_pu: tuple = (0.0, 0.0)  # (R, X), system base

    def to_json(self) -> dict:
        """JSON-ready (inf as "inf")."""
        out = asdict(self)
        out["limits_pu"] = ["inf" if math.isinf(b) else b for b in self.limits_pu]
        return {key: list(value) if isinstance(value, tuple) else value for key, value in out.items()}


def screen_law(name: str, net, settings: ScreenSettings):
    """The network law ``name`` at every generator of ``net`` with the screen's gains: the one place a law is chosen.

    The NNI laws with the screen's gains; a speed law with the controller node's default gains (config/controller.yaml).
    """
    if name not in AVAILABLE_LAWS:
        raise ValueError(f"unknown law {name!r} (laws: {', '.join(AVAILABLE_LAWS)})")
    gains = law_from_parameters(name, controller_defaults(), ControllerParams()).gains
    return NetworkLaw.uniform(net, settings.tau_s, settings.gain_k, settings.gain_l, settings.alpha,
                              settings.reference, name=name, gains=gains)


#: The columns of a screen's rows, in order (what the Parquet parts hold).
ROW_COLUMNS = ("contingency", "kind", "fault_bus", "line", "law", "b", "reference", "cct_s", "bracket_low_s",
               "bracket_high_s", "at_search_limit", "clearing_time_s", "verdict", "loss_at_s", "weakest_generator",
               "weakest_swing_deg")


def _verdict_at(net, law, fault, limits, settings) -> list[tuple]:
    """Per b: (verdict, loss instant s or None, weakest generator, its largest COI-relative swing in degrees)."""
    traj = simulate_network(net, law, fault, limits, settings.duration_s, settings.rate_hz, drop_lost_runs=True)
    spread = angle_spread(traj.delta_rad)
    swing = np.abs(traj.coi_angles() - traj.coi_angles()[:1])
    out = []
    for r in range(len(limits)):
        lost = np.flatnonzero(spread[:, r] > POLE_SLIP_RAD)
        weakest = int(np.nanargmax(np.nanmax(swing[:, :, r], axis=0)))
        if lost.size:
            loss_s = float(traj.t_s[lost[0]])
            words = FIRST_SWING_LOSS if loss_s <= settings.clearing_time_s + FIRST_SWING_S else LATER_LOSS
        else:
            loss_s, words = None, IN_SYNCHRONISM
        out.append((words, loss_s, net.names[weakest], float(np.degrees(np.nanmax(swing[:, weakest, r])))))
    return out


def screen_chunk(spec: CaseSpec, settings: ScreenSettings, names: tuple) -> dict:
    """The rows of the contingencies ``names`` (every law and b of each), and the seconds spent computing them.

    What one task of the screen runs, on a worker or in the serial path alike.
    Returns ``{"rows": [...], "compute_s": float}``; each row has :data:`ROW_COLUMNS`.
    """
    started = time.perf_counter()
    net = network_of(spec)
    impedance = complex(*settings.fault_impedance_pu)
    rows = []
    for name in names:
        contingency = parse_contingency(net, name)
        trip = () if contingency.branch is None else (contingency.branch,)

        def fault(clearing_s, bus=contingency.bus, trip=trip):
            return BusFault(net, bus, clearing_s, impedance, trip)

        for law_name in settings.laws:
            law = screen_law(law_name, net, settings)
            limits = list(settings.limits_pu)
            found = critical_clearing_times(net, law, fault, limits, settings.duration_s, settings.rate_hz,
                                            high_s=settings.cct_max_s, resolution_s=settings.resolution_s,
                                            points=settings.points)
            verdicts = _verdict_at(net, law, fault(settings.clearing_time_s), limits, settings)
            for b, (cct, bracket, at_limit), (words, loss_s, weakest, swing_deg) in zip(limits, found, verdicts):
                rows.append({
                    "contingency": contingency.name, "kind": contingency.kind, "fault_bus": contingency.bus,
                    "line": None if contingency.line is None else "-".join(map(str, contingency.line[:2]))
                    + f":{contingency.line[2]}",
                    "law": law_name, "b": float(b), "reference": settings.reference, "cct_s": cct,
                    "bracket_low_s": bracket[0], "bracket_high_s": bracket[1], "at_search_limit": bool(at_limit),
                    "clearing_time_s": settings.clearing_time_s, "verdict": words, "loss_at_s": loss_s,
                    "weakest_generator": weakest, "weakest_swing_deg": swing_deg})
    return {"rows": rows, "compute_s": time.perf_counter() - started}


def warm_up() -> float:
    """Load (or compile) the network's RK4 in this process: a tiny run of Kundur's case. Returns its seconds."""
    from nni_plant_sim.integrators import advance
    from nni_plant_sim.network_scenarios import AngleDisplacement

    started = time.perf_counter()
    net = network_of(CaseSpec("kundur_two_area"))
    x = np.stack((net.delta_bar_rad, np.zeros(net.size)))[:, :, None]
    advance(0.0, 0.02, x, np.zeros((net.size, 1)), net, AngleDisplacement(np.zeros(net.size)), 1e-3)
    return time.perf_counter() - started
