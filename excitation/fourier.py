"""Swevers' finite Fourier series: periodic joint trajectories with analytic derivatives.

    q_i(t)   = q0_i + sum_l  a_il/(w l) sin(w l t) - b_il/(w l) cos(w l t)
    dq_i(t)  =        sum_l  a_il cos(w l t) + b_il sin(w l t)
    ddq_i(t) =        sum_l -a_il w l sin(w l t) + b_il w l cos(w l t),     w = 2 pi f0, l = 1..H

For a torque-driven (underactuated) system the same coefficients define the drive torque as the
velocity-form series, tau_i(t) = sum_l a_il cos(w l t) + b_il sin(w l t) (zero mean, periodic).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FourierDesign"]


@dataclass(frozen=True)
class FourierDesign:
    """A periodic excitation: H harmonics of a base frequency for each of n joints.

    Attributes:
        base_freq_hz: f0, the fundamental [Hz]; the period is 1/f0.
        a: (n, H) sine-velocity coefficients [rad/s] (or [N m] for a torque design).
        b: (n, H) cosine-velocity coefficients [rad/s] (or [N m]).
        q0: (n,) offsets [rad] (ignored for a torque design).
    """

    base_freq_hz: float
    a: np.ndarray
    b: np.ndarray
    q0: np.ndarray

    def __post_init__(self) -> None:
        if self.base_freq_hz <= 0:
            raise ValueError(f"base_freq_hz must be > 0, got {self.base_freq_hz}")
        if self.a.ndim != 2 or self.a.shape != self.b.shape or self.q0.shape != (self.a.shape[0],):
            raise ValueError(f"shapes a {self.a.shape}, b {self.b.shape}, q0 {self.q0.shape} do not form (n, H), (n,)")

    @property
    def n_joints(self) -> int:
        return self.a.shape[0]

    @property
    def harmonics(self) -> int:
        return self.a.shape[1]

    @property
    def period_s(self) -> float:
        return 1.0 / self.base_freq_hz

    def _phases(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        w = 2 * np.pi * self.base_freq_hz
        wl = w * np.arange(1, self.harmonics + 1)  # (H,)
        arg = np.asarray(t, dtype=float)[:, None] * wl  # (N, H)
        return np.sin(arg), np.cos(arg), wl

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q, dq, ddq, each (N, n), at times t (N,) [s]."""
        s, c, wl = self._phases(t)
        q = self.q0 + s @ (self.a / wl).T - c @ (self.b / wl).T
        dq = c @ self.a.T + s @ self.b.T
        ddq = -s @ (self.a * wl).T + c @ (self.b * wl).T
        return q, dq, ddq

    def torque(self, t: np.ndarray) -> np.ndarray:
        """(N, n) drive torque of a torque design at times t (N,) [N m]."""
        return self.evaluate(t)[1]

    def basis(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Linear maps from the coefficients to q - q0, dq, ddq: each (N, 2H), columns [a_1..a_H, b_1..b_H]."""
        s, c, wl = self._phases(t)
        return (
            np.hstack([s / wl, -c / wl]),
            np.hstack([c, s]),
            np.hstack([-s * wl, c * wl]),
        )

    def scaled(self, factor: float | np.ndarray) -> FourierDesign:
        """The same shape with every amplitude multiplied by `factor`, one number or (n,) one per joint (offsets
        kept)."""
        f = np.asarray(factor, dtype=float)
        f = f[:, None] if f.ndim == 1 else f
        return FourierDesign(self.base_freq_hz, self.a * f, self.b * f, self.q0)

    def to_vector(self) -> np.ndarray:
        """Flat parameter vector [a (n*H), b (n*H), q0 (n)]."""
        return np.concatenate([self.a.ravel(), self.b.ravel(), self.q0])

    @classmethod
    def from_vector(cls, x: np.ndarray, *, n_joints: int, harmonics: int, base_freq_hz: float) -> FourierDesign:
        k = n_joints * harmonics
        if x.shape != (2 * k + n_joints,):
            raise ValueError(f"vector of shape {x.shape}, expected ({2 * k + n_joints},)")
        return cls(
            base_freq_hz,
            x[:k].reshape(n_joints, harmonics).copy(),
            x[k : 2 * k].reshape(n_joints, harmonics).copy(),
            x[2 * k :].copy(),
        )
