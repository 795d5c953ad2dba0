"""WingRock with an unknown, delayed aileron gain (the SKI paper's delay experiment).

ṗ = Σ_j w_j δ[k−j] + Δ*(θ, p), j = 0 … 7: the candidate basis is the last
eight inputs (carried as exact memory), Δ* the known WingRock term. The true
plant applies δ[k−6] with gain 3, so w_6 = 3 and every other w_j = 0.
"""
from skigen import Model
from skigen.library import delayed_inputs

from .wingrock import DT, NOISE_STD, W_TRUE

WINDOW = 8
TRUE_DELAY = 6


def build(prior_variance=1.0, process_std=(1e-4, 1e-3), window=WINDOW, name="wingrock_delay", weight_std=0.0):
    """The delay model; ``window`` candidate delays 0 … window−1 (``weight_std``: their random walk)."""
    model = Model(name, dt=DT, discretization="rk4")
    theta = model.state("theta", unit="deg", role="angle", std=1.0, process_std=process_std[0])
    p = model.state("p", unit="deg/s", role="rate", std=1.0, process_std=process_std[1])
    delta = model.input("delta", unit="deg")
    known = sum(w * b for w, b in zip(W_TRUE, [1, theta, p, abs(theta) * p, abs(p) * p, theta ** 3]))
    model.dynamics({theta: p, p: known})
    model.output("phi", theta, unit="deg", noise_std=NOISE_STD)
    model.unknown(p, delayed_inputs(model, delta, window), prior_variance=prior_variance, process_std=weight_std)
    return model


model = build()
# Forty-eight candidate delays (n = 50): too large to unroll, emitted with the looped C kernel.
wide = build(window=48, name="wingrock_delay48")
