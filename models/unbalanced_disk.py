"""The unbalanced disc (a DC-motor-driven pendulum, TU/e), as a VISCOUS-ONLY
pendulum: the nominal model a user would start from.

    θ̈ = −OMEGA0² sin θ − GAMMA θ̇ + KU u

The real disc also has Coulomb friction (−Fc·sign θ̇), which `skigen diagnose`
should find. OMEGA0, GAMMA, KU were fitted by output error on the first 80 %
of the record (examples/fit_linear_nominals.py). Data: ../shared/data/unbalanced_disk.csv.
"""
import casadi as ca

from skigen import Model

DT = 0.025                          # s
OMEGA0, GAMMA, KU = 11.3281, 1.95806, 31.9657   # rad/s, 1/s, rad/(s² V)
TRAIN_FRACTION = 0.8
NOISE_STD = 2e-3                    # rad (encoder step 2π/2000 ≈ 3.1e-3)


def build(omega0=OMEGA0, gamma=GAMMA, ku=KU, name="unbalanced_disk"):
    model = Model(name, dt=DT, discretization="rk4")
    theta = model.state("theta", unit="rad", role="angle", std=0.1, process_std=1e-4)
    w = model.state("w", unit="rad/s", role="rate", std=1.0, process_std=1e-2)
    u = model.input("u", unit="V")
    model.dynamics({theta: w, w: -omega0 ** 2 * ca.sin(theta) - gamma * w + ku * u})
    model.output("th", theta, unit="rad", noise_std=NOISE_STD)
    return model


model = build()
