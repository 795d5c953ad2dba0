"""Fit the nominal (linear-physics) models of the two laboratory benchmarks.

These are the users' "simulation" models that `skigen diagnose` starts from:
a linear oscillator for the Silverbox and a viscous-only pendulum for the
unbalanced disc, each fitted by output error (free-run simulation) on the
training data with the model's own RK4 discretisation. The printed values are
the ones written in models/silverbox.py and models/unbalanced_disk.py.

    python examples/fit_linear_nominals.py        (needs ../shared/data)
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import scipy.optimize as opt
import scipy.signal as sig

from models import silverbox, unbalanced_disk
from skigen.recording import read_recording


def rk4_matrices(A, B, h, substeps):
    """Exact RK4 transition of the linear system ẋ = A x + B u (u held), substeps of h/substeps."""
    hs = h / substeps
    M = hs * A
    Phi = np.eye(len(A)) + M + M @ M / 2 + M @ M @ M / 6 + M @ M @ M @ M / 24
    Gam = hs * (np.eye(len(A)) + M / 2 + M @ M / 6 + M @ M @ M / 24) @ B
    Ad, Bd = np.eye(len(A)), np.zeros_like(B)
    for _ in range(substeps):
        Ad, Bd = Phi @ Ad, Phi @ Bd + Gam
    return Ad, Bd


def silverbox_sim(p, u, dt, substeps):
    k, d, b, c = p
    Ad, Bd = rk4_matrices(np.array([[0, 1], [-k, -d]]), np.array([[0], [b]]), dt, substeps)
    return sig.dlsim(sig.dlti(Ad, Bd, np.array([[1, 0]]), np.zeros((1, 1)), dt=dt), u)[1][:, 0] + c


def fit_silverbox(data: Path):
    rec = read_recording(data / "silverbox_snls80mv.csv", ["V1"], ["V2"])
    u, y = rec.inputs[:, 0], rec.outputs[:, 0]
    train = slice(*silverbox.TRAIN)
    sim = lambda p, s: silverbox_sim(p, u[s], silverbox.DT, silverbox.SUBSTEPS)
    p0 = [silverbox.K, silverbox.D, silverbox.B, silverbox.OFFSET]
    sol = opt.least_squares(lambda p: sim(p, train) - y[train], p0, x_scale=np.abs(p0) + 1e-3)
    print("silverbox K, D, B, OFFSET =", ", ".join(f"{v:.6g}" for v in sol.x))
    for name, (a, b) in silverbox.TESTS.items():
        e = sim(sol.x, slice(a, b))[50:] - y[a + 50:b]
        print(f"  simulation RMSE {name}: {1e3 * np.sqrt(np.mean(e ** 2)):.2f} mV")


def fit_disk(data: Path):
    from skigen.simulate import free_run
    rec = read_recording(data / "unbalanced_disk.csv", ["u"], ["th"])
    n_train = int(unbalanced_disk.TRAIN_FRACTION * len(rec.t))
    u, y = rec.inputs[:n_train], rec.outputs[:n_train, 0]

    def residual(p):
        model = unbalanced_disk.build(*p)
        return free_run(model, u, x0=[y[0], 0.0])[1][:, 0] - y
    p0 = [unbalanced_disk.OMEGA0, unbalanced_disk.GAMMA, unbalanced_disk.KU]
    sol = opt.least_squares(residual, p0, x_scale=np.abs(p0))
    print("unbalanced disk OMEGA0, GAMMA, KU =", ", ".join(f"{v:.6g}" for v in sol.x))
    tail_u, tail_y = rec.inputs[n_train:], rec.outputs[n_train:, 0]
    e = free_run(unbalanced_disk.build(*sol.x), tail_u, x0=[tail_y[0], 0.0])[1][:, 0] - tail_y
    print(f"  simulation RMSE on the held-out last 20 %: {np.sqrt(np.mean(e ** 2)):.4f} rad")


if __name__ == "__main__":
    data = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[2] / "shared" / "data")
    fit_silverbox(data)
    fit_disk(data)
