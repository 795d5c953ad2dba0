"""Reference of the recovery policy (skigen/guard.py) in covariance form: test oracle.

Written from the policy's statement, not from the C or the stepper: the gate on the
normalised innovation, the restart of the physical states and the bound on the prior
stds, each on a covariance P.
"""
import numpy as np


def gate_mask(e, Pyy, valid, gate):
    """Outputs rejected by the gate: valid ones with |e_i| > gate·√Pyy_ii (or not finite)."""
    e, v = np.asarray(e, float), np.diag(np.asarray(Pyy, float))
    with np.errstate(invalid="ignore", over="ignore"):
        ok = np.abs(e) <= gate * np.sqrt(np.maximum(v, 0))
    return np.asarray(valid, bool) & ~ok


def restart(z, P, nx, z0, P0, scale):
    """Mean and covariance with the first nx states at (z0, scale·P0), uncorrelated with the rest."""
    z, P = np.array(z, float), np.array(P, float)
    z[:nx] = z0[:nx]
    P[:nx, :] = 0.0
    P[:, :nx] = 0.0
    P[:nx, :nx] = scale * np.asarray(P0)[:nx, :nx]
    return z, P


def bound(P, std_max):
    """P scaled so that no state's std exceeds std_max: D P D, D_ii = min(1, std_max_i / std_i)."""
    sd = np.sqrt(np.diag(P))
    d = np.minimum(1.0, np.asarray(std_max) / np.where(sd > 0, sd, 1))
    return P * d[:, None] * d[None, :]
