"""Silverbox as a grey box: the Duffing oscillator with every constant declared
as a parameter, for `skigen fit` (Wigren & Schoukens, ECC 2013).

    ÿ = −k y − d ẏ − k3 y³ + b V1,    V2 = y + offset

The input is interpolated linearly over each sample (first-order hold): the
circuit is driven by a smooth signal, and holding it constant over the sample
costs about 10 mV of simulation error. Starting values are the linear fit of
models/silverbox.py (k3 = 0). Data: ../shared/data/silverbox_*.csv;
`python examples/silverbox_greybox.py` fits it on the standard training range.
"""
from skigen import Model

from models.silverbox import B, D, DT, K, OFFSET, SUBSTEPS, TESTS, TRAIN  # noqa: F401  (the protocol)

NOISE_STD = 1e-3                    # V, measurement (and model-error) allowance


def build(name="silverbox_greybox", hold="foh", cubic=True):
    """The grey box; ``cubic=False`` gives the linear oscillator with the same parameters."""
    model = Model(name, dt=DT, discretization="rk4", substeps=SUBSTEPS, input_hold=hold)
    y = model.state("y", unit="V", role="position", std=0.05, process_std=1e-5)
    v = model.state("v", unit="V/s", role="velocity", std=50.0, process_std=1e-2)
    u = model.input("V1", unit="V")
    k = model.parameter("k", K, unit="1/s^2", bounds=(0, 1e7))
    d = model.parameter("d", D, unit="1/s", bounds=(0, 1e4))
    b = model.parameter("b", B, unit="1/s^2")
    offset = model.parameter("offset", OFFSET, unit="V")
    rate = -k * y - d * v + b * u
    if cubic:
        rate -= model.parameter("k3", 0.0, unit="1/(V^2 s^2)") * y ** 3
    model.dynamics({y: v, v: rate})
    model.output("V2", y + offset, unit="V", noise_std=NOISE_STD)
    return model


model = build()
linear = build(name="silverbox_linear", cubic=False)   # the linear nominal `skigen diagnose` starts from
