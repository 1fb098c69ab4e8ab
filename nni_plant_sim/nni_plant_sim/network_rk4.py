"""The network's RK4 over a stretch with its powers held, compiled: what :func:`.integrators.advance` runs for a network.

A lockstep period at 50 frames/s is 20 RK4 steps of 4 stages, one after the
other: 80 evaluations of the swing equations of N generators on the plant's
critical path. In numpy each evaluation is some 7 calls of ~0.3-0.8 us on
arrays of 4 to 52 entries, and the stages' sums as many again: 415-570 us a
period at N = 4 to 52, more than the fan-out floor's round trip at N = 4
(measured). Compiled as one loop (numba, cached on disk after the first
compilation, ~1 s; a later process loads it in ~0.2 s, numba's import
included): 28 / 41 / 186 us a period at N = 4 / 10 / 52, this module's
preparation of the arrays (11 us) included.

The arithmetic is :func:`.network.network_acceleration` (the general form,
which :func:`.model.plant_rate` and the generic :func:`.integrators.rk4` use)
and :func:`.integrators._rk4_swing`'s sums, term by term in the same order;
the double sum of :func:`.network.electrical_power` is summed left to right
here where numpy's matrix product (BLAS) groups it its own way, and the sines
are libm's, so the two agree to rounding, not to the bit
(tests/test_network.py pins this loop to the generic RK4 of plant_rate). The
plant node and the offline simulations both integrate a network through it,
so a lockstep run still equals the offline one to rounding. Each run of a
batch is computed alone, in the same operations whatever the batch's size.
Pure numpy and numba: no ROS import.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from nni_plant_sim.network import Switched


@numba.njit(cache=True)
def _accelerations(delta, speed, columns, sources, which, drive, damping, inertia, trig, sums, out):
    """delta'' of every generator and run into ``out`` (N, R); run r in the coupling ``which[r]``.

    ``columns[k]`` is coupling k's ``block`` transposed: each row's sum runs over j in order, all rows at once
    (the inner loop over rows vectorises; measured at N = 52: 280 -> 186 us a period).
    """
    n, runs = delta.shape
    for r in range(runs):
        column, source = columns[which[r]], sources[which[r]]
        for i in range(n):
            trig[i] = math.cos(delta[i, r])
            trig[n + i] = math.sin(delta[i, r])
        sums[:] = 0.0
        for j in range(2 * n):
            for m in range(2 * n):
                sums[m] += column[j, m] * trig[j]
        for i in range(n):
            p_electrical = trig[i] * sums[i] + trig[n + i] * sums[n + i] + source[i] * trig[i] + source[n + i] * trig[n + i]
            out[i, r] = (drive[i, r] - p_electrical - damping[i] * speed[i, r]) / inertia[i]


@numba.njit(cache=True)
def _stage(delta, speed, rate_delta, rate_speed, factor, stage_delta, stage_speed):
    """The state at a stage: ``(delta + factor k_delta, speed + factor k_speed)`` into the stage's arrays."""
    n, runs = delta.shape
    for i in range(n):
        for r in range(runs):
            stage_delta[i, r] = delta[i, r] + factor * rate_delta[i, r]
            stage_speed[i, r] = speed[i, r] + factor * rate_speed[i, r]


@numba.njit(cache=True)
def _rk4_steps(delta, speed, steps, h, columns, sources, which, drive, damping, inertia):
    """``steps`` RK4 steps of ``h`` s from (delta, speed), each (N, R); returns the new pair.

    Stage k_i = (k_i delta, k_i speed) = (the speed at the stage, its acceleration), as in ``_rk4_swing``.
    """
    n, runs = delta.shape
    delta, speed = delta.copy(), speed.copy()
    trig, sums = np.empty(2 * n), np.empty(2 * n)
    k1, k2, k3, k4 = np.empty((n, runs)), np.empty((n, runs)), np.empty((n, runs)), np.empty((n, runs))
    stage, speed2, speed3, speed4 = np.empty((n, runs)), np.empty((n, runs)), np.empty((n, runs)), np.empty((n, runs))
    half, sixth = 0.5 * h, h / 6.0
    for _ in range(steps):
        _accelerations(delta, speed, columns, sources, which, drive, damping, inertia, trig, sums, k1)
        _stage(delta, speed, speed, k1, half, stage, speed2)
        _accelerations(stage, speed2, columns, sources, which, drive, damping, inertia, trig, sums, k2)
        _stage(delta, speed, speed2, k2, half, stage, speed3)
        _accelerations(stage, speed3, columns, sources, which, drive, damping, inertia, trig, sums, k3)
        _stage(delta, speed, speed3, k3, h, stage, speed4)
        _accelerations(stage, speed4, columns, sources, which, drive, damping, inertia, trig, sums, k4)
        for i in range(n):
            for r in range(runs):
                delta[i, r] = delta[i, r] + sixth * (speed[i, r] + 2.0 * speed2[i, r] + 2.0 * speed3[i, r]
                                                     + speed4[i, r])
                speed[i, r] = speed[i, r] + sixth * (k1[i, r] + 2.0 * k2[i, r] + 2.0 * k3[i, r] + k4[i, r])
    return delta, speed


def rk4_network(delta, speed, steps: int, h: float, net, p_mech_pu, coupling, battery_power_pu) -> tuple:
    """``steps`` RK4 steps of ``h`` s of the network ``net`` with ``(p_mech_pu, coupling)`` in force.

    ``delta`` and ``speed`` (rad, rad/s) have shape (N,) or (N, R);
    ``battery_power_pu`` broadcasts against them; ``coupling`` is a
    :class:`.network.Coupling` or a :class:`.network.Switched` (one of two per
    run). Returns ``(delta, speed)`` of the same shape.

    A coupling's arrays come made (``Coupling.columns``, ``.sources``): building them at every call
    (transpose, concatenate, copy) and broadcasting the drive cost about 60 of the 100 us of a
    lockstep period at N = 10 (timeit), the compiled loop 40.
    """
    shape, n = np.shape(delta), net.size
    drive = np.empty(shape)
    drive[...] = p_mech_pu[(slice(None),) + (None,) * (len(shape) - 1)] + battery_power_pu
    drive = drive.reshape(n, -1)
    runs = drive.shape[1]
    if isinstance(coupling, Switched):
        columns = np.concatenate((coupling.first.columns, coupling.second.columns))
        sources = np.concatenate((coupling.first.sources, coupling.second.sources))
        which = own(np.broadcast_to(np.where(coupling.use_first, 0, 1), (runs,)), np.int64)
    else:
        columns, sources, which = coupling.columns, coupling.sources, np.zeros(runs, np.int64)
    delta, speed = _rk4_steps(own(delta).reshape(n, runs), own(speed).reshape(n, runs), int(steps),
                              float(h), columns, sources, which, drive, own(net.damping_pu), own(net.inertia_m))
    return delta.reshape(shape), speed.reshape(shape)


def own(value, dtype=float):
    """A writable C array of its own: one compiled signature for every call."""
    return np.array(value, dtype=dtype, order="C")
