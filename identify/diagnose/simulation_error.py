"""Simulation error: re-start the simulation from the measured state every window and compare the angles.

A model that is right predicts the motion, not only the torque. Every `window_s` the simulator is reset to
the (filtered) measured state and driven open loop by the measured torque (zero-order hold between
samples, mapped back to the applied torque by the sensor model) for one window; the error is the RMS over
all windows of simulated minus measured joint angles. MuJoCo models run batched through `mujoco.rollout`;
other models (the authors' closed-form ones) pass a forward-dynamics function.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np
from mujoco import rollout

from dynamics.actuators import actuation_of, as_motors

__all__ = ["SimulationError", "Stepper", "mujoco_stepper", "ode_stepper", "simulation_error"]

# (q0 (B, nv), dq0 (B, nv), tau (B, n_step, nv), dt) -> q (B, n_step, nv) after each step
Stepper = Callable[[np.ndarray, np.ndarray, np.ndarray, float], np.ndarray]


@dataclass(frozen=True)
class SimulationError:
    """Windowed re-start simulation against the measurement.

    Attributes:
        rms: (nv,) RMS of simulated minus measured angle over every window [rad].
        time: (M,) sample times compared [s].
        q_simulated: (M, nv) simulated angles at those times [rad] (restarting every window).
        window_s: window length [s].
        windows: windows simulated.
        of: windows the record holds (`windows` < `of` where `max_windows` thinned them).
    """

    rms: np.ndarray
    time: np.ndarray
    q_simulated: np.ndarray
    window_s: float
    windows: int
    of: int


_BATCH = 1000  # windows simulated in one batch


def mujoco_stepper(model: mujoco.MjModel) -> tuple[Stepper, float]:
    """A batched stepper over `mujoco.rollout` for an MJCF, driven by the measured joint torques through its
    actuators (servos made plain motors, `dynamics.actuators.as_motors`), and its dt.

    The torque a calibrated MJCF's sensor reports is turned into the applied one first (`torque_sensor`), then
    into each actuator's ctrl through its own gear, gain and constant force (`Actuation.ctrl_for_torque`):
    ctrl = tau / gear applied gainprm x the torque before, wrong on any actuator of gain != 1."""
    from identify.diagnose.calibrate import torque_sensor  # the calibrated file's convention lives there

    sensor_gain, sensor_offset = torque_sensor(model)
    model = as_motors(model, "the replayed model")
    actuation = actuation_of(model, "the replayed model")  # no actuator's force depends on the state any more
    spec = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
    data = mujoco.MjData(model)
    size = mujoco.mj_stateSize(model, spec)

    def step(q0: np.ndarray, dq0: np.ndarray, tau: np.ndarray, dt: float) -> np.ndarray:
        states = np.empty((len(q0), size))
        for b in range(len(q0)):
            mujoco.mj_resetData(model, data)
            data.qpos[:], data.qvel[:] = q0[b], dq0[b]
            mujoco.mj_getState(model, data, states[b], spec)
        applied = (tau - sensor_offset) / sensor_gain
        still = np.zeros_like(applied)  # the state: no term of a state-free actuator reads it
        ctrl = actuation.ctrl_for_torque(applied, still, still)
        out, _ = rollout.rollout(model, data, states, ctrl)
        return out[:, :, 1 : 1 + model.nq]

    return step, float(model.opt.timestep)


def ode_stepper(
    accel: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray], dt: float = 5e-4
) -> tuple[Stepper, float]:
    """A batched semi-implicit Euler stepper for `accel(q, dq, tau) -> ddq` (each (B, nv))."""

    def step(q0: np.ndarray, dq0: np.ndarray, tau: np.ndarray, h: float) -> np.ndarray:
        q, dq = q0.copy(), dq0.copy()
        out = np.empty(tau.shape)
        for i in range(tau.shape[1]):
            dq = dq + h * accel(q, dq, tau[:, i])
            q = q + h * dq
            out[:, i] = q
        return out

    return step, dt


def simulation_error(
    stepper: tuple[Stepper, float],
    time: np.ndarray,
    q: np.ndarray,
    dq: np.ndarray,
    tau_applied: np.ndarray,
    *,
    window_s: float = 0.25,
    max_windows: int | None = None,
) -> SimulationError:
    """Re-start every `window_s` from (q, dq) and drive by `tau_applied`; compare with q.

    Args:
        stepper: (batched stepper, physics timestep [s]).
        time: (N,) sample times [s] of one record.
        q, dq: (N, nv) measured (filtered) angles [rad] and velocities [rad/s]: the start states and the
            reference the simulation is compared with.
        tau_applied: (N, nv) joint torque applied over [t_k, t_k+1) [N m].
        window_s: window length [s].
        max_windows: simulate at most this many windows, spread evenly over the whole record (the first and the
            last among them): a long record's error is estimated at a bounded cost. None: every window.
    """
    step, dt = stepper
    if window_s <= 0:
        raise ValueError(f"window_s must be > 0, got {window_s}")
    if max_windows is not None and max_windows < 1:
        raise ValueError(f"max_windows must be >= 1 or None, got {max_windows}")
    n_step = max(int(round(window_s / dt)), 1)
    starts = []
    k = 0
    while k < len(time) and time[k] + n_step * dt <= time[-1]:
        starts.append(k)
        k = int(np.searchsorted(time, time[k] + n_step * dt, side="left"))
    if not starts:
        raise ValueError(
            f"the record ({time[-1] - time[0]:.3f} s) is shorter than one re-started simulation window "
            f"(diagnose.window_s = {window_s} s): give a shorter window"
        )
    simulated = starts
    if max_windows is not None and len(starts) > max_windows:  # evenly spread, the first and the last among them
        simulated = [starts[i] for i in np.unique(np.round(np.linspace(0, len(starts) - 1, max_windows)).astype(int))]
    times, sims, refs = [], [], []
    for first in range(0, len(simulated), _BATCH):  # a batch of windows at a time: memory stays that of a batch
        idx = np.array(simulated[first : first + _BATCH])
        t_phys = time[idx][:, None] + dt * np.arange(n_step)[None, :]
        sample = np.clip(np.searchsorted(time, t_phys + 1e-12, side="right") - 1, 0, len(time) - 1)
        q_sim = step(q[idx], dq[idx], tau_applied[sample], dt)  # (B, n_step, nv): after steps 1..n_step
        t_after = t_phys + dt
        for b, k0 in enumerate(idx):
            k1 = int(np.searchsorted(time, t_after[b, -1], side="right"))
            ks = np.arange(k0 + 1, k1)
            sim = np.column_stack([np.interp(time[ks], t_after[b], q_sim[b, :, j]) for j in range(q.shape[1])])
            times.append(time[ks])
            sims.append(sim)
            refs.append(q[ks])
    t_all, s_all, r_all = np.concatenate(times), np.concatenate(sims), np.concatenate(refs)
    rms = np.sqrt(np.mean((s_all - r_all) ** 2, axis=0))
    return SimulationError(
        rms=rms, time=t_all, q_simulated=s_all, window_s=float(window_s), windows=len(simulated), of=len(starts)
    )
