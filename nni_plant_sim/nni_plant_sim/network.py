"""Classical multi-machine network: swing equations coupled through a Kron-reduced admittance.

Pure numpy (and pypower for the load flow): no ROS import.

Generator i is a constant EMF ``E_i`` behind its internal impedance
``ra_i + j x'_d,i``; loads are constant impedances (from the load flow
voltages); the network is Kron-reduced to the internal nodes, ``Y = G + jB``:

    M_i delta_i'' = P_m,i + P_ST,i - P_e,i(delta) - D_i delta_i'
    P_e,i = sum_j E_i E_j (G_ij cos(delta_i - delta_j) + B_ij sin(delta_i - delta_j))
            + E_i V_s (G_is cos delta_i + B_is sin delta_i)      (a fixed source s, angle 0)

Per unit on the system base, angles in rad against the nominal-frequency
reference, speeds ``delta' = omega - omega0`` in rad/s, time in s. The paper's
single machine against an infinite bus is the case N = 1 with the infinite bus
as the fixed source and a lossless line (``G = 0``, ``E V_s B_is = P_max``):
:func:`electrical_power` then gives ``P_max sin(delta)`` to the last bit, and
:func:`swing_acceleration` is the swing equation both use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np


def swing_acceleration(p_mech_pu, battery_power_pu, p_electrical_pu, speed_rad_s, damping_pu, inertia_m):
    """Rotor acceleration delta'' in rad/s^2: ``(P_m + P_ST - P_e - D delta') / M``.

    The one swing equation: floats (the SMIB plant node's path) or numpy arrays
    (one entry per generator and run) alike.
    """
    return (p_mech_pu + battery_power_pu - p_electrical_pu - damping_pu * speed_rad_s) / inertia_m


@dataclass(frozen=True)
class Coupling:
    """The reduced network in force, as power coefficients between the internal EMFs.

    ``gc[i, j] = E_i E_j G_ij`` and ``bs[i, j] = E_i E_j B_ij`` (shape (N, N),
    pu); ``gc_source[i] = E_i V_s G_is`` and ``bs_source[i] = E_i V_s B_is``
    (shape (N,)) couple generator i to a fixed source at angle 0 (an infinite
    bus; zero for a network without one).
    """

    gc: np.ndarray
    bs: np.ndarray
    gc_source: np.ndarray
    bs_source: np.ndarray
    block: np.ndarray = field(init=False, repr=False)
    #: What the compiled RK4 (:mod:`.network_rk4`) takes, made once: ``block`` transposed, as a C array of one
    #: coupling (shape (1, 2N, 2N)), and the source terms ``[gc_source, bs_source]`` (shape (1, 2N)).
    columns: np.ndarray = field(init=False, repr=False)
    sources: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        # [[Gc, -Bs], [Bs, Gc]] @ [c; s] gives both sums of electrical_power in one product.
        block = np.block([[self.gc, -self.bs], [self.bs, self.gc]])
        object.__setattr__(self, "block", block)
        object.__setattr__(self, "columns", np.array(block.T, dtype=float, order="C")[None])
        object.__setattr__(self, "sources", np.concatenate((self.gc_source, self.bs_source)).astype(float)[None])


@dataclass(frozen=True)
class Switched:
    """Per run, one of two couplings: ``first`` where ``use_first`` (shape (R,)), else ``second``.

    Lets runs that differ only in when a fault clears share one vectorised integration.
    """

    first: Coupling
    second: Coupling
    use_first: np.ndarray


def electrical_power(delta_rad, coupling):
    """Electrical power P_e,i of every generator, pu system base.

    ``delta_rad`` has shape (N,) or (N, R) (R runs); returns the same shape.
    With ``c = cos(delta)``, ``s = sin(delta)`` the double sum is
    ``c (Gc c - Bs s) + s (Gc s + Bs c)``: 2N sines and cosines instead of N^2,
    both sums from one matrix product (``Coupling.block``).
    """
    if isinstance(coupling, Switched):
        return np.where(coupling.use_first, electrical_power(delta_rad, coupling.first),
                        electrical_power(delta_rad, coupling.second))
    c, s = np.cos(delta_rad), np.sin(delta_rad)
    n = c.shape[0]
    sums = coupling.block @ np.concatenate((c, s))
    column = (slice(None),) + (None,) * (np.ndim(delta_rad) - 1)
    return c * sums[:n] + s * sums[n:] + coupling.gc_source[column] * c + coupling.bs_source[column] * s


def network_acceleration(delta_rad, speed_rad_s, battery_power_pu, net: "Network", p_mech_pu, coupling):
    """Rotor accelerations of all generators (rad/s^2), shape of ``delta_rad``: (N,) or (N, R).

    ``p_mech_pu`` has shape (N,); ``battery_power_pu`` broadcasts against ``delta_rad``.
    """
    column = (slice(None),) + (None,) * (np.ndim(delta_rad) - 1)
    return swing_acceleration(p_mech_pu[column], battery_power_pu, electrical_power(delta_rad, coupling), speed_rad_s,
                              net.damping_pu[column], net.inertia_m[column])



@dataclass(frozen=True)
class Network:
    """A multi-machine system reduced to its generators' internal nodes, at its pre-fault equilibrium.

    Attributes (arrays of shape (N,), system base unless said otherwise)
    ----------
    names : tuple[str, ...]
        One label per generator (its bus, e.g. ``"G1@1"``).
    gen_bus : numpy.ndarray
        External bus number of each generator.
    mbase_mva : numpy.ndarray
        Machine rating (MVA); per-generator controller gains and battery limits
        are given in pu of it.
    base_mva : float
        System base (MVA).
    f0_hz : float
        Nominal frequency.
    inertia_m, damping_pu
        ``M_i = 2 H_i (mbase_i/base) / omega0`` and ``D_i`` (pu power per rad/s).
    emf_pu : numpy.ndarray
        ``|E_i|``.
    delta_bar_rad, p_mech_pu
        Pre-fault equilibrium angles (from the load flow, reference as the
        case's slack) and mechanical powers ``P_m,i = P_e,i(delta_bar)``.
    coupling : Coupling
        The pre-fault reduced network.
    bus_model : BusModel or None
        What faults are built from (None for the SMIB, which has no buses).
    """

    names: tuple
    gen_bus: np.ndarray
    mbase_mva: np.ndarray
    base_mva: float
    f0_hz: float
    inertia_m: np.ndarray
    damping_pu: np.ndarray
    emf_pu: np.ndarray
    delta_bar_rad: np.ndarray
    p_mech_pu: np.ndarray
    coupling: Coupling
    bus_model: "BusModel | None" = None

    @property
    def size(self) -> int:
        """Number of generators N."""
        return len(self.names)

    @classmethod
    def from_smib(cls, plant) -> "Network":
        """The paper's SMIB (an :class:`nni_plant_sim.model.SmibParams`) as N = 1 against an infinite bus."""
        zero = np.zeros((1, 1))
        return cls(names=("G",), gen_bus=np.array([1]), mbase_mva=np.array([100.0]), base_mva=100.0,
                   f0_hz=plant.f0_hz, inertia_m=np.array([plant.inertia_m]),
                   damping_pu=np.array([plant.damping_pu]), emf_pu=np.array([1.0]),
                   delta_bar_rad=np.array([plant.delta_bar_rad]), p_mech_pu=np.array([plant.p_mech_pu]),
                   coupling=Coupling(zero, zero, np.zeros(1), np.array([plant.p_max_pu])))

    def coi(self, delta_rad):
        """Centre-of-inertia angle ``sum M_i delta_i / sum M_i`` of (N,) or (N, R) angles."""
        weights = self.inertia_m / self.inertia_m.sum()
        return np.tensordot(weights, delta_rad, axes=(0, 0))

    def pu_of_machine(self, value_pu_mbase):
        """Per-generator values given in pu of each machine's rating, on the system base."""
        return np.asarray(value_pu_mbase, dtype=float) * self.mbase_mva / self.base_mva

    def faulted(self, fault_bus: int, fault_impedance_pu: complex = 0.0, tripped=()) -> Coupling:
        """The reduced network with a three-phase fault at ``fault_bus`` through ``fault_impedance_pu``.

        ``tripped`` lists branch indices already out. A bolted fault (impedance 0)
        holds the bus at zero voltage, so the bus is eliminated as a ground node.
        """
        return self._need_buses().coupling(self.emf_pu, fault_bus=fault_bus, fault_impedance_pu=fault_impedance_pu,
                                           tripped=tripped)

    def without(self, tripped) -> Coupling:
        """The reduced network with the branches ``tripped`` (indices) out of service."""
        return self._need_buses().coupling(self.emf_pu, tripped=tripped)

    def _need_buses(self) -> "BusModel":
        if self.bus_model is None:
            raise ValueError("this system has no bus model (the SMIB): faults at buses do not apply")
        return self.bus_model


@dataclass(frozen=True)
class BusModel:
    """The full network (buses and branches) the reduced couplings are built from.

    ``ybus`` (n x n, system base) holds the branches and shunts; ``branch_y``
    the four admittances (yff, yft, ytf, ytt) and end buses of each branch, so
    that a trip subtracts it; ``load_y`` the constant-impedance loads from the
    load flow voltages; ``gen_index`` the internal bus index of each generator's
    terminal and ``gen_y = 1/(ra + j x'_d)``.
    """

    bus_numbers: np.ndarray
    ybus: np.ndarray
    branch_ends: np.ndarray
    branch_y: np.ndarray
    load_y: np.ndarray
    gen_index: np.ndarray
    gen_y: np.ndarray

    def bus_index(self, bus: int) -> int:
        """Internal index of an external bus number; ValueError naming the bus when absent."""
        where = np.flatnonzero(self.bus_numbers == bus)
        if where.size != 1:
            raise ValueError(f"bus {bus} is not in the case (buses {int(self.bus_numbers.min())}.."
                             f"{int(self.bus_numbers.max())})")
        return int(where[0])

    def branch_index(self, from_bus: int, to_bus: int, circuit: int = 1) -> int:
        """Index of the ``circuit``-th branch (1-based, in case order) between two buses, either direction."""
        f, t = self.bus_index(from_bus), self.bus_index(to_bus)
        matches = np.flatnonzero(((self.branch_ends[:, 0] == f) & (self.branch_ends[:, 1] == t))
                                 | ((self.branch_ends[:, 0] == t) & (self.branch_ends[:, 1] == f)))
        if not 1 <= circuit <= matches.size:
            raise ValueError(f"no circuit {circuit} between buses {from_bus} and {to_bus} "
                             f"(the case has {matches.size})")
        return int(matches[circuit - 1])

    def reduced_admittance(self, fault_bus=None, fault_impedance_pu: complex = 0.0, tripped=()) -> np.ndarray:
        """Kron reduction to the internal nodes: ``Y_gg - Y_gb Y_bb^-1 Y_bg`` (N x N complex)."""
        y_bb = self.ybus + np.diag(self.load_y)
        for k in tripped:
            f, t = self.branch_ends[k]
            yff, yft, ytf, ytt = self.branch_y[k]
            y_bb[f, f] -= yff
            y_bb[f, t] -= yft
            y_bb[t, f] -= ytf
            y_bb[t, t] -= ytt
        n, m = len(self.bus_numbers), len(self.gen_index)
        np.add.at(y_bb, (self.gen_index, self.gen_index), self.gen_y)
        y_bg = np.zeros((n, m), dtype=complex)
        y_bg[self.gen_index, np.arange(m)] = -self.gen_y
        keep = np.arange(n)
        if fault_bus is not None:
            k = self.bus_index(fault_bus)
            if fault_impedance_pu == 0:
                keep = keep[keep != k]
            else:
                y_bb[k, k] += 1.0 / fault_impedance_pu
        y_bb, y_bg = y_bb[np.ix_(keep, keep)], y_bg[keep]
        return np.diag(self.gen_y) - y_bg.T @ np.linalg.solve(y_bb, y_bg)

    def coupling(self, emf_pu, **fault) -> Coupling:
        """Power coefficients ``E_i E_j G_ij``, ``E_i E_j B_ij`` of the reduced network (no fixed source)."""
        y = self.reduced_admittance(**fault)
        ee = np.outer(emf_pu, emf_pu)
        zero = np.zeros(len(emf_pu))
        return Coupling(ee * y.real, ee * y.imag, zero, zero)


@dataclass(frozen=True)
class Machine:
    """Classical-model data of one generator, pu on its own rating (as in a PSS/E DYR GENCLS record).

    bus : int
        External bus number of the generator.
    mbase_mva : float
        Machine rating, MVA.
    inertia_h_s : float
        Inertia constant H, s (MW s / MVA of the rating).
    xd_prime_pu, ra_pu : float
        Transient reactance x'_d and armature resistance, pu machine base.
    damping_pu : float
        Damping D, pu power (machine base) per pu speed.
    """

    bus: int
    mbase_mva: float
    inertia_h_s: float
    xd_prime_pu: float
    ra_pu: float = 0.0
    damping_pu: float = 0.0

    def __post_init__(self) -> None:
        for name in ("mbase_mva", "inertia_h_s", "xd_prime_pu"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"generator at bus {self.bus}: {name} must be finite and positive, got {value}")
        for name in ("ra_pu", "damping_pu"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"generator at bus {self.bus}: {name} must be finite and >= 0, got {value}")


def solve_load_flow(ppc: dict, tolerance_pu: float = 1e-11) -> dict:
    """Newton load flow of a MATPOWER-format case with pypower; the solved case (external numbering).

    Raises ValueError when it does not converge.
    """
    from pypower.api import ppoption, runpf

    options = ppoption(VERBOSE=0, OUT_ALL=0, PF_TOL=tolerance_pu, PF_MAX_IT=30)
    result, success = runpf(ppc, options)
    if not success:
        raise ValueError("the load flow did not converge")
    return result


def network_from_case(ppc: dict, machines, f0_hz: float, tolerance_pu: float = 1e-11) -> Network:
    """Solve the load flow of a MATPOWER-format case and reduce it to the generators' internal nodes.

    ``ppc`` holds ``baseMVA``, ``bus``, ``gen`` and ``branch`` in MATPOWER's
    column layout; ``machines`` one :class:`Machine` per in-service generator,
    in the order of the case's gen table.
    """
    from pypower.idx_brch import BR_STATUS, F_BUS, T_BUS
    from pypower.idx_bus import BUS_I, PD, QD, VA, VM
    from pypower.idx_gen import GEN_BUS, GEN_STATUS, PG, QG
    from pypower.makeYbus import makeYbus

    solved = solve_load_flow(ppc, tolerance_pu)
    base = float(solved["baseMVA"])
    bus, branch = solved["bus"], solved["branch"][solved["branch"][:, BR_STATUS] > 0]
    gen = solved["gen"][solved["gen"][:, GEN_STATUS] > 0]
    machines = tuple(machines)
    if len(machines) != len(gen):
        raise ValueError(f"the case has {len(gen)} generators in service but {len(machines)} machine records")
    numbers = bus[:, BUS_I].astype(int)
    index = {int(b): i for i, b in enumerate(numbers)}
    for machine, row in zip(machines, gen):
        if machine.bus != int(row[GEN_BUS]):
            raise ValueError(f"machine records must follow the case's gen table: bus {machine.bus} "
                             f"where the case has bus {int(row[GEN_BUS])}")
    internal = bus.copy()
    internal[:, BUS_I] = np.arange(len(bus))
    internal_branch = branch.copy()
    internal_branch[:, F_BUS] = [index[int(b)] for b in branch[:, F_BUS]]
    internal_branch[:, T_BUS] = [index[int(b)] for b in branch[:, T_BUS]]
    ybus, yf, yt = (np.asarray(m.todense()) for m in makeYbus(base, internal, internal_branch))
    ends = internal_branch[:, [F_BUS, T_BUS]].astype(int)
    rows = np.arange(len(branch))
    branch_y = np.column_stack((yf[rows, ends[:, 0]], yf[rows, ends[:, 1]], yt[rows, ends[:, 0]], yt[rows, ends[:, 1]]))
    voltage = bus[:, VM] * np.exp(1j * np.radians(bus[:, VA]))
    load_y = (bus[:, PD] - 1j * bus[:, QD]) / base / np.abs(voltage) ** 2
    gen_index = np.array([index[int(b)] for b in gen[:, GEN_BUS]])
    mbase = np.array([m.mbase_mva for m in machines])
    z_internal = np.array([complex(m.ra_pu, m.xd_prime_pu) for m in machines]) * base / mbase
    current = np.conj((gen[:, PG] + 1j * gen[:, QG]) / base / voltage[gen_index])
    emf = voltage[gen_index] + z_internal * current
    model = BusModel(numbers, ybus, ends, branch_y, load_y, gen_index, 1.0 / z_internal)
    coupling = model.coupling(np.abs(emf))
    delta_bar = np.angle(emf)
    provisional = Network(
        names=tuple(f"G{i + 1}@{int(b)}" for i, b in enumerate(gen[:, GEN_BUS])), gen_bus=gen[:, GEN_BUS].astype(int),
        mbase_mva=mbase, base_mva=base, f0_hz=f0_hz,
        inertia_m=np.array([2.0 * m.inertia_h_s * m.mbase_mva / base for m in machines]) / (2.0 * math.pi * f0_hz),
        damping_pu=np.array([m.damping_pu * m.mbase_mva / base for m in machines]) / (2.0 * math.pi * f0_hz),
        emf_pu=np.abs(emf), delta_bar_rad=delta_bar, p_mech_pu=np.zeros(len(machines)), coupling=coupling,
        bus_model=model)
    return replace(provisional, p_mech_pu=electrical_power(delta_bar, coupling))
