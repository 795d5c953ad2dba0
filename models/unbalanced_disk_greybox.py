"""The unbalanced disc as a grey box, with the benchmark's common model and its
constants declared as parameters, for `skigen fit`:

    θ̈ = −omega0² sin θ − gamma θ̇ − fc tanh(θ̇ / W) + ku u,    th = θ

Starting values are the viscous-only fit of models/unbalanced_disk.py (fc = 0).
W, the velocity over which the Coulomb friction changes sign, is a constant of
the model (the benchmark's 0.001 rad/s is sharper than one sample resolves at
dt = 0.025 s; see examples/unbalanced_disk_greybox.py). Data: ../shared/data/unbalanced_disk.csv.
"""
import casadi as ca

from skigen import Model

from models.unbalanced_disk import DT, GAMMA, KU, NOISE_STD, OMEGA0, TRAIN_FRACTION  # noqa: F401

W = 0.05                            # rad/s, Coulomb smoothing width


def build(name="unbalanced_disk_greybox", width=W, substeps=1, coulomb=True, diagnosed=False):
    """The grey box; ``coulomb=False`` gives the viscous-only pendulum with the same parameters;
    ``diagnosed=True`` adds what `skigen diagnose` names beside the friction: the motor acting one
    sample late (u[k−1]) and a constant torque (bias, rad/s²)."""
    model = Model(name, dt=DT, discretization="rk4", substeps=substeps)
    theta = model.state("theta", unit="rad", role="angle", std=0.1, process_std=1e-4)
    w = model.state("w", unit="rad/s", role="rate", std=1.0, process_std=1e-2)
    u = model.input("u", unit="V")
    omega0 = model.parameter("omega0", OMEGA0, unit="rad/s", bounds=(0, 100))
    gamma = model.parameter("gamma", GAMMA, unit="1/s", bounds=(0, 100))
    ku = model.parameter("ku", KU, unit="rad/(s^2 V)")
    drive = model.input_history(u, 1)[0] if diagnosed else u
    rate = -omega0 ** 2 * ca.sin(theta) - gamma * w + ku * drive
    if coulomb:
        rate -= model.parameter("fc", 0.0, unit="rad/s^2") * ca.tanh(w / width)
    if diagnosed:
        rate += model.parameter("bias", 0.0, unit="rad/s^2")
    model.dynamics({theta: w, w: rate})
    model.output("th", theta, unit="rad", noise_std=NOISE_STD)
    return model


model = build()
viscous = build(name="unbalanced_disk_viscous", coulomb=False)   # the nominal `skigen diagnose` starts from
