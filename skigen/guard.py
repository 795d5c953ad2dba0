"""Outlier gating and recovery: the policy every filter step follows, in C and in Python.

Per sample, around the derived step (``<prefix>_step`` in ``filter.c.in``, and
:class:`skigen.runtime.PythonStepper`, the same rules line by line):

1. **Bad input.** A non-finite input: the state is predicted with its last finite value (0
   before any), as a recording holds an input through a hole, and no reading is used (an
   update under a wrong input would teach it to the weights); the gap grows. A step
   skipped would leave the state a sample behind the vehicle from then on.
2. **Stuck sensor.** A finite reading equal, bit for bit, to the previous one of that
   output for ``stuck_limit`` samples in a row is not used (0: never).
3. **Recovery.** When one of the present outputs had its last ``reject_limit`` readings
   rejected (gate or numerical failure; each output counts its own run, which its next
   used reading ends), or when ``gap_limit`` samples have passed without a measurement
   used and the gate would reject one of the present readings (or the step fails), the
   physical states restart: their mean at the declared initial value, their covariance
   the declared one times ``reinit_scale`` and uncorrelated with the rest; the weights
   and estimated parameters keep their mean and covariance. That sample then updates
   without the gate; the widened covariance lets the next readings through it while the
   states settle. A reading the prediction still explains after a gap is simply used (a
   position fix every 1000 samples is not a dropout). So an output the others outvote (a heading 200° off while the gyro is used)
   restarts the states at its next reading, and a sensor that stays faulty restarts
   them every ``reject_limit`` of its readings: raise ``reject_limit`` to trust the others.
4. **Gate.** Otherwise a measurement whose innovation is more than ``gate`` standard
   deviations, |e_i| > gate·√(Pyy_ii), is rejected (counted per output) and the step
   runs again without it: a rejected sample never changes the state (0: no gate).
5. **Numerical failure.** A non-finite result is rejected and the prior kept.
6. **Bounded prediction.** The prior's standard deviation of every augmented state i
   is at most ``std_max[i]`` (``std_scale`` times its declared initial std; inf:
   none): beyond it the state's row of the factor S (or row and column of P) is scaled
   down, so a long dropout cannot overflow the covariance.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["Guard", "bound_std", "chol_psd", "reinit"]


@dataclass(frozen=True)
class Guard:
    """The recovery policy's settings (defaults of the generated C's settings struct).

    gate: innovation gate in standard deviations per output (0: off).
    reject_limit: readings of one output rejected in a row before a restart at its next one (0: never).
    gap_limit: samples without a used measurement after which a reading the gate rejects restarts (0: never).
    stuck_limit: identical readings in a row from which an output counts as stuck (0: off).
    reinit_scale: variance multiple of the declared initial covariance at a restart.
    std_scale: bound on each prior std, as a multiple of its declared initial std (inf: none).
    """

    gate: float = 5.0
    reject_limit: int = 25
    gap_limit: int = 500
    stuck_limit: int = 10
    reinit_scale: float = 100.0
    std_scale: float = 100.0

    def __post_init__(self):
        for name in ("reject_limit", "gap_limit", "stuck_limit"):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and v >= 0):
                raise ValueError(f"Guard.{name} must be a non-negative integer, got {v!r}")
        # As the C's <prefix>_settings_check, which refuses the settings otherwise.
        for name, fine, what in (("gate", lambda v: 0 <= v < np.inf, "a finite number >= 0"),
                                 ("reinit_scale", lambda v: 0 < v < np.inf, "a finite number > 0"),
                                 ("std_scale", lambda v: v > 0, "a number > 0 (inf: no bound)")):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and fine(v)):
                raise ValueError(f"Guard.{name} must be {what}, got {v!r}")

    @classmethod
    def off(cls) -> "Guard":
        """No policy beyond holding a bad input and rejecting a non-finite step: no gate, no
        stuck-sensor test, no restart, no bound on the prior std (what the ``casadi`` backend of
        :func:`skigen.runtime.run` does where no step fails)."""
        return cls(gate=0.0, reject_limit=0, gap_limit=0, stuck_limit=0, std_scale=float("inf"))

    def std_max(self, P0: np.ndarray) -> np.ndarray:
        """The bound on each augmented state's prior std (inf where the declared std is 0)."""
        sd = np.sqrt(np.diag(P0))
        return np.where(sd > 0, self.std_scale * sd, np.inf)

    def asdict(self) -> dict:
        return asdict(self)


def chol_psd(P: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of a positive semi-definite P; a non-positive pivot gives a zero column."""
    n = len(P)
    L = np.zeros((n, n))
    for j in range(n):
        d = P[j, j] - L[j, :j] @ L[j, :j]
        if d > 0:
            L[j, j] = np.sqrt(d)
            L[j + 1:, j] = (P[j + 1:, j] - L[j + 1:, :j] @ L[j, :j]) / L[j, j]
    return L


def reinit(z, C, nx: int, z0, C0, scale: float, square_root: bool):
    """(z, C) with the first nx states restarted at (z0, scale·P0) and uncorrelated with the
    rest, which keeps its mean and covariance. C, C0: factors S (square_root) or covariances P."""
    z, C = np.array(z, float), np.array(C, float)
    z[:nx] = z0[:nx]
    if square_root:
        F = C[nx:, :]
        rest = chol_psd(F @ F.T)
        C = np.zeros_like(C)
        C[:nx, :nx] = np.sqrt(scale) * C0[:nx, :nx]
        C[nx:, nx:] = rest
    else:
        C[:nx, :] = 0.0
        C[:, :nx] = 0.0
        C[:nx, :nx] = scale * C0[:nx, :nx]
    return z, C


def bound_std(C, std_max, square_root: bool, held: list | None = None):
    """C with every state's std at most std_max: its row of S (or row and column of P) scaled;
    ``held``: a list given gets the mask of the states scaled appended."""
    C = np.array(C, float)
    with np.errstate(over="ignore"):          # as in C: a row too large to square gets d = 0
        sd = np.sqrt(np.sum(C * C, axis=1)) if square_root else np.sqrt(np.clip(np.diag(C), 0, None))
    d = np.where(sd > std_max, std_max / np.where(sd > 0, sd, 1), 1.0)
    if held is not None:
        held.append(d < 1)
    return d[:, None] * C if square_root else d[:, None] * C * d[None, :]
