"""The EKF's compiled linear algebra (for :mod:`.ekf`): the per-feature innovation covariances
and the Joseph-form update with the accepted features."""

import numba
import numpy as np


@numba.njit(cache=True)
def innovation_blocks(H, P, sigma2):
    """Per-feature innovation covariances ``S_j = C_j P C_j^T + sigma_j^2 I`` (m, 2, 2)."""
    m = len(sigma2)
    HP = H @ P
    S = np.empty((m, 2, 2))
    for j in range(m):
        for a in range(2):
            for b in range(2):
                S[j, a, b] = np.dot(HP[2 * j + a], H[2 * j + b])
        S[j, 0, 0] += sigma2[j]
        S[j, 1, 1] += sigma2[j]
    return S


@numba.njit(cache=True)
def joseph_update(x, P, H, nu, sigma2, accepted):
    """State and covariance updated with the accepted features' rows of ``H`` (2m, n),
    innovations ``nu`` (m, 2) and pixel variances ``sigma2`` (m,): Joseph form."""
    n_acc = int(accepted.sum())
    rows = np.empty(2 * n_acc, dtype=np.int64)
    r = np.empty(2 * n_acc)
    z = np.empty(2 * n_acc)
    i = 0
    for j in range(len(nu)):
        if accepted[j]:
            for a in range(2):
                rows[i] = 2 * j + a
                r[i] = sigma2[j]
                z[i] = nu[j, a]
                i += 1
    Ha = H[rows]
    HP = Ha @ P
    Sa = HP @ Ha.T
    for i in range(len(r)):
        Sa[i, i] += r[i]
    K = np.linalg.solve(Sa, HP).T  # P H^T S^-1 (S and P symmetric)
    x_new = x + K @ z
    IKH = np.eye(len(x)) - K @ Ha
    P_new = IKH @ P @ IKH.T + (K * r) @ K.T
    return x_new, 0.5 * (P_new + P_new.T)
