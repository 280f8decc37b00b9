"""The model without accelerations: momentum form, the thesis's omega/(s + omega) filtering, energy form.

Lagrange's equations give tau = d/dt (M(q) dq) + n(q, dq) with n = C dq + g - dM/dt dq, both linear in the
base parameters:

    tau = d/dt [P(q, dq) beta] + N(q, dq) beta,   P beta = M(q) dq,   N beta = (C dq + g - dM/dt dq)

P comes from the regressor as W(q, 0, dq) - W(q, 0, 0) (inverse dynamics at zero speed is M ddq + g), and
dM/dt dq as the derivative of P(q + eps dq, dq) in eps. Filtering both sides by F = omega / (s + omega)
removes the derivative (thesis eq. 2.23-2.26, 5.13): F[d/dt x] = omega (x - F x) when F x starts at x(0),
so

    F tau = [omega (P - F P) + F N] beta = psi beta          (no acceleration anywhere)

The energy form multiplies by dq: tau' dq = d/dt H + dissipated power, H the total mechanical energy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from identify.problem import Problem

__all__ = ["FilteredModel", "filtered_model", "lowpass", "momentum_form", "span", "torque_sigma"]


def span(problem: Problem) -> slice:
    """The contiguous rows from the first to the last trusted one (filters need every sample)."""
    rows = np.flatnonzero(problem.rows)
    return slice(int(rows[0]), int(rows[-1]) + 1)


def momentum_form(problem: Problem, *, eps: float = 1e-5) -> tuple[np.ndarray, np.ndarray]:
    """P and N of the base parameters on the problem's contiguous span.

    Args:
        problem: uses its states' q and dq (never ddq).
        eps: step of the central difference along dq for dM/dt dq [s].

    Returns:
        P, N: each (n, nv, r) with M dq = P beta [kg m^2/s] and tau = d/dt(P beta) + N beta [N m].
    """
    rows = span(problem)
    q, dq = problem.states.q[rows], problem.states.dq[rows]
    zero = np.zeros_like(dq)
    model, base = problem.model, problem.base

    def momentum(qq: np.ndarray) -> np.ndarray:
        return base.columns(model.regressor(qq, zero, dq) - model.regressor(qq, zero, zero))

    P = momentum(q)
    mdot_dq = (momentum(q + eps * dq) - momentum(q - eps * dq)) / (2 * eps)
    N = base.columns(model.regressor(q, dq, zero)) - mdot_dq
    return P, N


def lowpass(x: np.ndarray, omega: float, dt: float, *, initial: np.ndarray | None = None) -> np.ndarray:
    """omega / (s + omega) along axis 0, discretised by the bilinear (Tustin) transform.

    Args:
        x: (n, ...) samples at interval dt.
        omega: the filter's corner [rad/s].
        dt: sample interval [s].
        initial: (...) value of the output at the first sample; None: zero, as the continuous filter
            started at rest.
    """
    c = omega * dt / (2.0 + omega * dt)
    b, a = np.array([c, c]), np.array([1.0, (omega * dt - 2.0) / (2.0 + omega * dt)])
    flat = x.reshape(len(x), -1)
    start = np.zeros(flat.shape[1]) if initial is None else np.reshape(initial, -1)
    # state of the transposed direct form that makes y[0] = start (y[0] = c x[0] + z[0])
    out, _ = signal.lfilter(b, a, flat, axis=0, zi=(start - c * flat[0])[None, :])
    return out.reshape(x.shape)


@dataclass(frozen=True)
class FilteredModel:
    """The filtered, acceleration-free model F tau = psi beta on the problem's span.

    Attributes:
        time: (n,) sample times [s].
        psi: (n, nv, r) filtered regressor.
        y: (n, nv) filtered torque [N m].
        settled: (n,) False during the filter's start-up (a few time constants).
    """

    time: np.ndarray
    psi: np.ndarray
    y: np.ndarray
    settled: np.ndarray


def filtered_model(problem: Problem, *, omega: float, settle_s: float | None = None) -> FilteredModel:
    """psi and F tau of the thesis's eq. 2.23-2.26 (see the module docstring).

    Args:
        problem: states q, dq and torque on its span.
        omega: filter corner [rad/s]; it should sit above the excitation's bandwidth.
        settle_s: start-up skipped afterwards [s] (default 3 / omega).
    """
    if omega <= 0:
        raise ValueError(f"omega must be > 0 rad/s, got {omega}")
    rows = span(problem)
    time = problem.data.time[rows]
    dt = float(np.median(np.diff(time)))
    P, N = momentum_form(problem)
    psi = omega * (P - lowpass(P, omega, dt, initial=P[0])) + lowpass(N, omega, dt)
    y = lowpass(problem.data.tau[rows], omega, dt)
    settled = time - time[0] >= (settle_s if settle_s is not None else 3.0 / omega)
    return FilteredModel(time, psi, y, settled)


def torque_sigma(problem: Problem, beta: np.ndarray) -> np.ndarray:
    """(nv,) residual std of the measured torque against the problem's (unfiltered) regressor [N m]."""
    resid = problem.y - np.einsum("knr,r->kn", problem.W, beta)
    dof = max(problem.W.shape[0] - problem.W.shape[2] / problem.W.shape[1], 1.0)
    return np.sqrt(np.sum(resid**2, axis=0) / dof)
