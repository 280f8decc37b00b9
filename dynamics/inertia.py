"""Inertia algebra of one body's 10 standard parameters (m, MX, MY, MZ, XX, XY, YY, XZ, YZ, ZZ).

The parameters are the mass m, the first moment h = m c and the inertia I about the frame's origin. A body is
physically consistent exactly when its pseudo-inertia

    J = [[Sigma, h], [h', m]],    Sigma = tr(I)/2 * 1 - I

is positive definite (Wensing, Kim and Slotine 2017). Writing J = U U' with U upper triangular and a
positive diagonal, U = e^a [[e^d1, s12, s13, t1], [0, e^d2, s23, t2], [0, 0, e^d3, t3], [0, 0, 0, 1]]
(Rucker and Wensing 2022), every real vector (a, d, s, t) gives a consistent body and every consistent body
has such a vector (the log-Cholesky parametrisation).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "body_and_jacobian",
    "body_from_log_cholesky",
    "from_mass_com_inertia",
    "from_pseudo_inertia",
    "is_consistent",
    "log_cholesky_from_body",
    "mass_com_inertia",
    "pseudo_inertia",
    "repair_body",
    "skew",
    "transform_parameters",
]


def skew(v: np.ndarray) -> np.ndarray:
    """(3, 3) cross-product matrix of v (3,)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def transform_parameters(params: np.ndarray, new_from_old: np.ndarray) -> np.ndarray:
    """(10,) the same body's parameters in another frame; `new_from_old` (4, 4) is the old frame's pose in it.

    Linear in `params` (unlike pin.Inertia, which divides by the mass to find the centre).
    """
    m, h = params[0], params[1:4]
    xx, xy, yy, xz, yz, zz = params[4:]
    inertia = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    R, p = new_from_old[:3, :3], new_from_old[:3, 3]
    rh = R @ h
    shifted = R @ inertia @ R.T - (skew(p) @ skew(rh) + skew(rh) @ skew(p)) - m * skew(p) @ skew(p)
    return np.array([m, *(rh + m * p), *shifted[[0, 0, 1, 0, 1, 2], [0, 1, 1, 2, 2, 2]]])


def from_mass_com_inertia(m: float, c: np.ndarray, inertia: np.ndarray) -> np.ndarray:
    """(10,) parameters at the origin from mass, centre of mass (3,) and inertia about it (3, 3)."""
    origin = inertia + m * (np.dot(c, c) * np.eye(3) - np.outer(c, c))
    return np.array([m, *(m * c), origin[0, 0], origin[0, 1], origin[1, 1], origin[0, 2], origin[1, 2], origin[2, 2]])


def pseudo_inertia(body: np.ndarray) -> np.ndarray:
    """(4, 4) pseudo-inertia of one body's 10 parameters (m, MX, MY, MZ, XX, XY, YY, XZ, YZ, ZZ)."""
    m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = body
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    J = np.empty((4, 4))
    J[:3, :3] = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    J[:3, 3] = J[3, :3] = hx, hy, hz
    J[3, 3] = m
    return J


def from_pseudo_inertia(J: np.ndarray) -> np.ndarray:
    """(..., 4, 4) pseudo-inertia -> (..., 10) body parameters (linear; the inverse of `pseudo_inertia`)."""
    S = J[..., :3, :3]
    return np.stack(
        [
            J[..., 3, 3],
            J[..., 0, 3],
            J[..., 1, 3],
            J[..., 2, 3],
            S[..., 1, 1] + S[..., 2, 2],
            -S[..., 0, 1],
            S[..., 0, 0] + S[..., 2, 2],
            -S[..., 0, 2],
            -S[..., 1, 2],
            S[..., 0, 0] + S[..., 1, 1],
        ],
        axis=-1,
    )


# where each of the 10 variables (a, d1, d2, d3, s12, s23, s13, t1, t2, t3) sits in U (a scales all of U)
_ENTRY = ((0, 0), (1, 1), (2, 2), (0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3))


def body_and_jacobian(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(10,) consistent body parameters from 10 unconstrained numbers, and their (10, 10) Jacobian."""
    a, d1, d2, d3 = np.clip(x[:4], -40.0, 40.0)
    s12, s23, s13, t1, t2, t3 = x[4:]
    scale = np.exp(a)
    U = scale * np.array(
        [[np.exp(d1), s12, s13, t1], [0.0, np.exp(d2), s23, t2], [0.0, 0.0, np.exp(d3), t3], [0.0, 0.0, 0.0, 1.0]]
    )
    dU = np.zeros((10, 4, 4))
    dU[0] = U
    for i, (r, c) in enumerate(_ENTRY):
        dU[i + 1, r, c] = U[r, c] if i < 3 else scale
    dJ = dU @ U.T
    dJ = dJ + np.swapaxes(dJ, 1, 2)
    return from_pseudo_inertia(U @ U.T), from_pseudo_inertia(dJ).T


def body_from_log_cholesky(x: np.ndarray) -> np.ndarray:
    """(10,) consistent body parameters from the 10 unconstrained numbers (a, d1, d2, d3, s12, s23, s13, t1-3)."""
    return body_and_jacobian(np.asarray(x, float))[0]


def log_cholesky_from_body(body: np.ndarray, *, floor: float = 1e-9) -> np.ndarray:
    """Inverse of `body_from_log_cholesky`; an inconsistent body is first lifted to eigenvalues >= floor * m."""
    J = pseudo_inertia(body)
    w, V = np.linalg.eigh(J)
    J = (V * np.maximum(w, floor * max(abs(body[0]), 1e-6))) @ V.T
    # U U' = J with U upper triangular: reverse-order Cholesky
    flip = np.eye(4)[::-1]
    L = np.linalg.cholesky(flip @ J @ flip)
    U = flip @ L @ flip
    a = np.log(U[3, 3])
    U = U / U[3, 3]
    return np.array([a, *np.log(np.diag(U)[:3]), U[0, 1], U[1, 2], U[0, 2], U[0, 3], U[1, 3], U[2, 3]])


def mass_com_inertia(theta: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, centre of mass (3,) and inertia about it (3, 3) from 10 standard parameters at the body origin."""
    m = float(theta[0])
    c = theta[1:4] / m
    xx, xy, yy, xz, yz, zz = theta[4:]
    origin = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    return m, c, origin - m * (np.dot(c, c) * np.eye(3) - np.outer(c, c))


_MARGIN = 1e-7


def _margin(w: np.ndarray) -> float:
    """[kg m^2] the MJCF text keeps about six significant digits, and MuJoCo checks A + B >= C on them."""
    return _MARGIN + 1e-5 * float(np.max(np.abs(w)))


def is_consistent(theta: np.ndarray) -> bool:
    """Positive mass, positive definite inertia about the centre of mass and the triangle inequality, with a
    margin that survives the MJCF text's rounding."""
    if theta[0] <= 0:
        return False
    w = np.sort(np.linalg.eigvalsh(mass_com_inertia(theta)[2]))
    return bool(w[0] > _margin(w) and w[0] + w[1] - w[2] > _margin(w))


def repair_body(theta: np.ndarray, nominal: np.ndarray, free: np.ndarray, notes: list[str], body: str) -> np.ndarray:
    """The corrected parameters if they are physically consistent; otherwise repaired where the data is blind.

    Directions the data does not see (for a planar arm: the inertia about in-plane axes) may leave a body
    with an inertia that is not positive definite; those entries (`free`, (10,) bool) are raised until
    it is, which changes no predicted torque. Only if no such entry exists is the inertia about the centre
    of mass itself repaired (a note says so).
    """
    if is_consistent(theta):
        return theta
    fixed = theta.copy()
    if fixed[0] <= 0:
        fixed[0] = nominal[0]
        notes.append(f"{body}: the fitted mass was not positive; nominal mass kept")
    diagonal = [i for i in (4, 6, 9) if free[i]]
    if diagonal:
        raised, step = fixed.copy(), 1e-7
        while not is_consistent(raised) and step < 1.0:
            raised[diagonal] = fixed[diagonal] + step
            step *= 1.5
        if is_consistent(raised):
            notes.append(
                f"{body}: unobservable inertia entries raised by {step / 1.5:.3g} kg m^2 (physical consistency)"
            )
            return raised
    m, c, inertia = mass_com_inertia(fixed)
    w, v = np.linalg.eigh(inertia)
    w = np.maximum(w, 2 * _margin(w))
    gap = 2 * _margin(w) + w.max() - (w.sum() - w.max())
    if gap > 0:  # triangle inequality of principal moments: raising all three by gap closes it
        w = w + gap
    inertia = v @ np.diag(w) @ v.T
    notes.append(f"{body}: inertia about the centre of mass raised to be physically consistent (changes predictions)")
    return from_mass_com_inertia(m, c, inertia)
