"""WingRock roll dynamics (the SKI paper, eqs. 30–32), in degrees.

θ̇ = p,  ṗ = L δ + Δ(θ, p),  L = 3,  Δ = w · [1, θ, p, |θ|p, |p|p, θ³].
Only the roll angle is measured (``phi``, noise 0.1 deg); the weights are
unknown, with true values W_TRUE.
"""
import numpy as np

from skigen import Model
from skigen.library import abs_products, polynomial, term

GAIN = 3.0                       # L, deg/s² per deg of aileron
W_TRUE = np.array([0.8, 0.2314, 0.6918, -0.6245, 0.0095, 0.0214])
DT = 0.02                        # s (50 Hz)
NOISE_STD = 0.1                  # deg
# Scale-aware prior used by the benchmarks and the demo: weight i has prior std
# PRIOR_ACCEL / rms(φ_i) over a typical flight, so every candidate may contribute
# about PRIOR_ACCEL deg/s² a priori (ski-math.md §6).
PRIOR_ACCEL = 10.0               # deg/s²
BASIS_RMS = np.array([1.0, 6.1, 8.2, 29.2, 122.4, 315.5])
PRIOR_VARIANCE = (PRIOR_ACCEL / BASIS_RMS) ** 2


def build(prior_variance=1.0, process_std=(1e-4, 1e-3), weight_std=0.0, name="wingrock"):
    """The WingRock model; keyword values are the filter settings of the benchmarks."""
    model = Model(name, dt=DT, discretization="rk4")
    theta = model.state("theta", unit="deg", role="angle", std=1.0, process_std=process_std[0])
    p = model.state("p", unit="deg/s", role="rate", std=1.0, process_std=process_std[1])
    delta = model.input("delta", unit="deg")
    model.dynamics({theta: p, p: GAIN * delta})
    model.output("phi", theta, unit="deg", noise_std=NOISE_STD)
    basis = (polynomial([theta, p], 1) + abs_products([(theta, p), (p, p)])
             + [term("theta^3", theta ** 3, key="theta3")])
    model.unknown(p, basis, prior_variance=prior_variance, process_std=weight_std)
    return model


model = build()
