"""Sensor model: sampling below the physics rate, Gaussian noise, quantisation, and sensor-side effects."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SensorModel", "quantise"]


def _zeros() -> np.ndarray:
    return np.zeros(0)


@dataclass(frozen=True)
class SensorModel:
    """How the true joint signals become measurements.

    Attributes:
        sample_rate_hz: rate of the measurements and of the (zero-order-hold) controller [Hz].
        sigma_q: std of the white noise on joint angles [rad].
        q_resolution: encoder step [rad]; 0 means no quantisation.
        sigma_tau: std of the white noise on measured torque [N m], one per joint (or a scalar).
        tau_resolution: torque quantisation step [N m]; 0 means none.
        joint_offset: (nv,) added to the reported angle [rad] (hidden effect; empty = none).
        torque_offset: (nv,) added to the reported torque [N m] (hidden effect; empty = none).
        torque_gain: (nv,) reported torque over applied torque (hidden effect; empty = 1).
        delay_s: the reported torque lags the applied torque by this much [s] (hidden effect).
    """

    sample_rate_hz: float = 500.0
    sigma_q: float = 0.0
    q_resolution: float = 0.0
    sigma_tau: float | np.ndarray = 0.0
    tau_resolution: float = 0.0
    joint_offset: np.ndarray = field(default_factory=_zeros)
    torque_offset: np.ndarray = field(default_factory=_zeros)
    torque_gain: np.ndarray = field(default_factory=_zeros)
    delay_s: float = 0.0

    def __post_init__(self) -> None:
        if self.sample_rate_hz <= 0:
            raise ValueError(f"sample_rate_hz must be > 0, got {self.sample_rate_hz}")
        for name in ("sigma_q", "q_resolution", "tau_resolution", "delay_s"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if np.any(np.asarray(self.sigma_tau) < 0):
            raise ValueError(f"sigma_tau must be >= 0, got {self.sigma_tau}")

    @property
    def noiseless(self) -> bool:
        return self.sigma_q == 0 and self.q_resolution == 0 and not np.any(self.sigma_tau) and self.tau_resolution == 0

    def measure_q(self, q: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(N, nv) true angles -> reported angles: offset, noise, then the encoder's quantisation."""
        out = q + (self.joint_offset if self.joint_offset.size else 0.0)
        if self.sigma_q > 0:
            out = out + rng.normal(0.0, self.sigma_q, size=q.shape)
        return quantise(out, self.q_resolution)

    def measure_tau(self, tau: np.ndarray, actuated: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(N, nv) applied torque -> reported torque (gain, offset, noise, quantisation) on actuated joints."""
        out = tau * (self.torque_gain if self.torque_gain.size else 1.0)
        out = out + (self.torque_offset if self.torque_offset.size else 0.0)
        sigma = np.broadcast_to(np.asarray(self.sigma_tau, dtype=float), (tau.shape[1],))
        out = out + rng.normal(size=tau.shape) * sigma
        return np.where(actuated, quantise(out, self.tau_resolution), 0.0)


def quantise(x: np.ndarray, step: float) -> np.ndarray:
    """Round to the nearest multiple of `step` (no-op for step 0)."""
    return x if step <= 0 else np.round(x / step) * step
