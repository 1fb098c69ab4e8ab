"""What a PMU at each generator would measure, from the classical model: phasors, frequency and its rate of change.

Pure numpy: no ROS import. The plants' C37.118 streams (:mod:`.pmu_stream`)
report these.

* Internal EMF E'_i = |E_i| exp(j delta_i): the constant EMF behind the
  transient reactance, its angle the rotor angle. The SMIB model fixes only
  P_max = E' V / X: its E' and its infinite bus are 1 pu (as
  :meth:`~.network.Network.from_smib`), the reactance 1/P_max.
* Terminal current and voltage of a network's generator (:func:`terminal_phasors`),
  from the Kron-reduced network in force: the current each internal node
  injects is I = Y_red E, i.e. I_i = (1/|E_i|) sum_j (gc_ij + j bs_ij) e^{j delta_j}
  with the coupling's coefficients gc = E_i E_j G_ij, bs = E_i E_j B_ij (and
  the fixed source's, if any), so that Re(E_i I_i*) is the swing equation's
  P_e,i exactly; the terminal voltage is V_i = E_i - (ra_i + j x'_d,i) I_i.
* Frequency f0 + delta'/(2 pi) Hz and its rate of change delta''/(2 pi) Hz/s,
  delta'' from the swing equation (:func:`~.model.plant_rate`) at the sample.
"""

from __future__ import annotations

import math

import numpy as np

from nni_plant_sim.model import plant_rate
from nni_plant_sim.network import Coupling, Network


def frequency_hz(speed_rad_s, f0_hz: float):
    """The rotor's electrical frequency, Hz, from its speed deviation delta' (rad/s)."""
    return f0_hz + np.asarray(speed_rad_s) / (2.0 * math.pi)


def rocof_hz_per_s(plant, network_in_force, delta_rad, speed_rad_s, battery_power_pu):
    """The frequency's rate of change delta''/(2 pi), Hz/s, at a state with its powers held.

    ``plant`` a :class:`~.model.SmibParams` (floats) or a :class:`~.network.Network` (arrays (N,)),
    ``network_in_force`` what its scenario's ``network(t, plant)`` gives, ``battery_power_pu`` on the
    plant's own base (a network's: the system base).
    """
    return plant_rate(0.0, (delta_rad, speed_rad_s), battery_power_pu, (plant, network_in_force))[1] / (2.0 * math.pi)


def terminal_phasors(net: Network, coupling: Coupling, delta_rad) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(E, I, V)``: each generator's internal EMF, the current it injects and its terminal voltage, complex pu
    on the system base, at rotor angles ``delta_rad`` (shape (N,)) with ``coupling`` in force.

    Needs the machines' internal impedances (``net.bus_model``): not for the SMIB.
    """
    if net.bus_model is None:
        raise ValueError("terminal phasors need the machines' impedances: this system has no bus model (the SMIB)")
    rotation = np.exp(1j * np.asarray(delta_rad, dtype=float))
    emf = net.emf_pu * rotation
    # Y_ij = (gc_ij + j bs_ij) / (|E_i| |E_j|), so E_i I_i* = sum_j (gc_ij - j bs_ij) e^{j(delta_i - delta_j)}
    # (+ the source's): its real part is electrical_power's P_e,i.
    current = ((coupling.gc + 1j * coupling.bs) @ rotation + coupling.gc_source + 1j * coupling.bs_source) \
        / net.emf_pu
    voltage = emf - current / net.bus_model.gen_y
    return emf, current, voltage
