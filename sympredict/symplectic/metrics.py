"""Error measures (trajectory error, Hamiltonian error, symplecticity defect) and the canonical ``J``.

``J = [[0, I], [-I, 0]]`` is defined here once: :func:`canonical_J` forms it,
:func:`j_times` applies it along an axis without forming it.
"""

from __future__ import annotations

import numpy as np

from sympredict._numeric import canonical_J, j_times  # J is defined once, in the foundation layer

__all__ = ["relative_trajectory_error", "relative_hamiltonian_error", "symplecticity_defect", "canonical_J", "j_times"]


def relative_trajectory_error(pred: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``|x_pred(t_k) - x_ref(t_k)|_2 / |x_ref(t_k)|_2`` (paper's measure (ii)).

    Parameters
    ----------
    pred, ref : ndarray of shape (B, K+1, 2n)

    Returns
    -------
    ndarray of shape (B, K+1)
    """
    if pred.shape != ref.shape:
        raise ValueError(f"pred and ref must have the same shape, got {pred.shape} and {ref.shape}")
    return np.linalg.norm(pred - ref, axis=-1) / np.linalg.norm(ref, axis=-1)


def relative_hamiltonian_error(system, traj: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """``|H(x_k) - H(x_0)| / |H(x_0)|`` along trajectories.

    Parameters
    ----------
    system
        Has ``hamiltonian(x (B, 2n), mu (B, d_mu)) -> (B,)``.
    traj : ndarray of shape (B, K+1, 2n)
    mu : ndarray of shape (B, d_mu)

    Returns
    -------
    ndarray of shape (B, K+1)
    """
    b, k1, dim = traj.shape
    mu = np.asarray(mu, dtype=float).reshape(b, -1)
    energy = system.hamiltonian(traj.reshape(-1, dim), np.repeat(mu, k1, axis=0)).reshape(b, k1)
    return np.abs(energy - energy[:, :1]) / np.abs(energy[:, :1])


def symplecticity_defect(jac: np.ndarray) -> np.ndarray:
    """``|DPhi^T J DPhi - J|_F`` per instance.

    Parameters
    ----------
    jac : ndarray of shape (B, 2n, 2n)

    Returns
    -------
    ndarray of shape (B,)
    """
    J = canonical_J(jac.shape[-1])
    return np.linalg.norm(np.swapaxes(jac, -1, -2) @ J @ jac - J, axis=(-2, -1))
