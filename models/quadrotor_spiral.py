"""Quadrotor translational dynamics with unknown thrust and drag (the SKI paper, section 4.2).

    ṗ = v
    v̇ = Σ_i w_i φ_i + g,       g = [0, 0, −9.81] m/s² (known)

States p = (px, py, pz) [m, world frame, z up] and v = (vx, vy, vz) [m/s];
inputs the attitude quaternion (qw, qx, qy, qz; body → world) and the mean
motor PWM [µs]; only the position is measured (outputs x, y, z, 0.02 m).

Candidate terms (each a DIRECTION with one shared weight over vx, vy, vz):

    "1", "pwm", "pwm^2", …, "pwm^5":  b3 · pwmₙᵏ       (thrust acceleration along body z)
    "drag_lin":                       −(I − b3 b3ᵀ) v  (linear rotor drag, in the rotor plane)
    "drag_quad":                      −v ‖v‖           (quadratic drag, |a| ∝ ‖v‖²)

where b3 = R(q) e3 is the body z axis and pwmₙ = (pwm − PWM_CENTER) / PWM_SCALE
is the centred, standardised PWM: PWM_CENTER = 1500 µs (the nominal hover
PWM, so the constant term carries the hover acceleration) and PWM_SCALE = 10 µs
(≈ the standard deviation of the PWM over the spiral climb, 7.8 µs on seed 0).
‖v‖ is computed as sqrt(v·v + 1e-12) so that it is differentiable at rest
(the EKF's Jacobian); the difference is below 1e-6 m/s.

The linear drag is rotor drag (blade flapping, induced drag): it acts on the
velocity in the rotor plane, not along the thrust axis (as in Gazebo's PX4
motor model). The simulator (models/quadrotor_sim.py) is linear in PWM with
linear rotor drag,
so in this basis the truth is W_TRUE: w_1 = THRUST_GAIN·(PWM_CENTER − 1000 µs)
= 9.81, w_pwm = THRUST_GAIN·PWM_SCALE = 0.1962, w_drag_lin = 0.3, all others 0.
"""
import casadi as ca
import numpy as np

from skigen import Model
from skigen.library import term

from . import quadrotor_sim as sim

DT = sim.SPIRAL["dt"]                 # s (50 Hz)
NOISE_STD = sim.NOISE_STD             # m
PWM_CENTER = 1500.0                   # µs, nominal hover PWM
PWM_SCALE = 10.0                      # µs, ≈ std of the PWM over the spiral
DEGREE = 5
TERMS = ["1", "pwm"] + [f"pwm^{k}" for k in range(2, DEGREE + 1)] + ["drag_lin", "drag_quad"]
W_TRUE = np.array([sim.THRUST_GAIN * (PWM_CENTER - sim.PWM_MIN), sim.THRUST_GAIN * PWM_SCALE,
                   0, 0, 0, 0, sim.DRAG_LIN, 0.0])
TRUE_TERMS = ["1", "pwm", "drag_lin"]
# RMS over the spiral (seed 0, true states) of the magnitude of each candidate (basis_rms).
BASIS_RMS = np.array([1.0, 0.842, 1.21, 2.25, 5.02, 12.8, 1.93, 4.81])
# Scale-aware prior: weight i has prior std PRIOR_ACCEL / BASIS_RMS_i, so that every
# candidate may a priori contribute about PRIOR_ACCEL m/s² of acceleration.
PRIOR_ACCEL = 1.0
PRIOR_VARIANCE = (PRIOR_ACCEL / BASIS_RMS) ** 2
# Process noise on v: the white-noise equivalent of the simulator's gust (OU, std σ,
# correlation time τ) at low frequency, σ·sqrt(2 τ dt) per sample; 1e-4 m on p.
PROCESS_STD = (1e-4, float(sim.GUST_STD * np.sqrt(2 * sim.GUST_TAU * DT)))


def build(prior_variance=PRIOR_VARIANCE, process_std=PROCESS_STD, weight_std=0.0, initial=(0.5, 0.0, 1.0),
          position_std=0.1, velocity_std=0.5, name="quadrotor_spiral"):
    """The spiral model. process_std: (position m, velocity m/s) per sample;
    initial: the initial position (the spiral's start), velocity 0."""
    model = Model(name, dt=DT, discretization="rk4")
    p = [model.state(f"p{a}", unit="m", role="position", initial=x0, std=position_std,
                     process_std=process_std[0]) for a, x0 in zip("xyz", initial)]
    v = [model.state(f"v{a}", unit="m/s", role="velocity", std=velocity_std, process_std=process_std[1])
         for a in "xyz"]
    qw, qx, qy, qz = (model.input(n) for n in ("qw", "qx", "qy", "qz"))
    pwm = model.input("pwm", unit="us")
    model.dynamics({p[0]: v[0], p[1]: v[1], p[2]: v[2], v[0]: 0, v[1]: 0, v[2]: -sim.G})
    for a, pa in zip("xyz", p):
        model.output(a, pa, unit="m", noise_std=NOISE_STD)
    model.unknown(v, basis(ca.vertcat(*v), ca.vertcat(qw, qx, qy, qz), pwm),
                  prior_variance=prior_variance, process_std=weight_std)
    return model


def basis(v, q, pwm):
    """The candidate terms as 3-vectors (directions), in the order of TERMS."""
    b3 = ca.vertcat(2 * (q[1] * q[3] + q[0] * q[2]), 2 * (q[2] * q[3] - q[0] * q[1]),
                    1 - 2 * (q[1] ** 2 + q[2] ** 2))
    u = (pwm - PWM_CENTER) / PWM_SCALE
    speed = ca.sqrt(ca.dot(v, v) + 1e-12)
    terms = [term("1", b3, key="one"), term("pwm", b3 * u, key="pwm")]
    terms += [term(f"pwm^{k}", b3 * u ** k, key=f"pwm{k}") for k in range(2, DEGREE + 1)]
    rotor_plane_v = v - b3 * ca.dot(b3, v)
    return terms + [term("drag_lin", -rotor_plane_v, key="drag_lin"),
                    term("drag_quad", -v * speed, key="drag_quad")]


def basis_values(vel, quat, pwm) -> np.ndarray:
    """Numeric candidates, (N, len(TERMS), 3), for true or estimated trajectories."""
    v, q, u = ca.SX.sym("v", 3), ca.SX.sym("q", 4), ca.SX.sym("u")
    f = ca.Function("phi", [v, q, u], [ca.horzcat(*[t.expr for t in basis(v, q, u)]).T])
    fm = f.map(len(pwm))
    out = np.asarray(fm(np.asarray(vel, float).T, np.asarray(quat, float).T, np.asarray(pwm, float)[None]))
    return out.reshape(len(TERMS), len(pwm), 3).transpose(1, 0, 2)


def basis_rms(flight) -> np.ndarray:
    """RMS over a flight of ‖φ_i‖ (how large each candidate is), per term."""
    phi = basis_values(flight.vel, flight.quat, flight.pwm)
    return np.sqrt(np.mean(np.sum(phi ** 2, axis=2), axis=0))


def recording(flight):
    """A simulated flight as a recording: attitude and PWM in, measured position out."""
    from skigen.recording import Recording
    return Recording("quadrotor spiral simulation", flight.t, np.column_stack([flight.quat, flight.pwm]),
                     flight.meas.copy(), ("qw", "qx", "qy", "qz", "pwm"), ("x", "y", "z"))


model = build()
