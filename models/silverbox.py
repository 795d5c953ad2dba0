"""Silverbox, an electronic Duffing oscillator (Wigren & Schoukens, ECC 2013), as a
LINEAR oscillator: the nominal model a user would start from.

    ÿ = −K y − D ẏ + B V1,    V2 = y + OFFSET

The true circuit adds a cubic stiffness −k₃ y³, which `skigen diagnose` should
find. K, D, B, OFFSET were fitted by output error on the training segment
(examples/fit_linear_nominals.py). Data: ../shared/data/silverbox_*.csv.
"""
from skigen import Model

DT = 1 / 610.35                     # s
SUBSTEPS = 2                        # RK4 steps per sample (ω·dt ≈ 0.73)
K, D, B, OFFSET = 197777.0, 44.3358, 192936.0, -0.00520514   # 1/s², 1/s, 1/s², V
TRAIN = (40650, 105712)             # samples of silverbox_snls80mv.csv
TESTS = {"arrow full": (100, 40575), "arrow no extrapolation": (100, 32100),
         "multisine": (105712, 127400)}
NOISE_STD = 1e-3                    # V, measurement (and model-error) allowance


def build(k=K, d=D, b=B, offset=OFFSET, name="silverbox"):
    model = Model(name, dt=DT, discretization="rk4", substeps=SUBSTEPS)
    y = model.state("y", unit="V", role="position", std=0.05, process_std=1e-5)
    v = model.state("v", unit="V/s", role="velocity", std=50.0, process_std=1e-2)
    u = model.input("V1", unit="V")
    model.dynamics({y: v, v: -k * y - d * v + b * u})
    model.output("V2", y + offset, unit="V", noise_std=NOISE_STD)
    return model


model = build()
