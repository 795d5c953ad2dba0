"""Vertical quadrotor dynamics from the raw mean PWM (the SKI paper, section 4.3).

    ż = v_z
    v̇_z = Σ_k w_k uᵏ − g,      k = 0 … 5,   g = 9.81 m/s² (known)

State [pz (m), vz (m/s)], input the mean motor PWM [µs], only pz measured
(output z, 0.02 m), 100 Hz. As in the paper's flight, the PWM is neither
centred on hover nor standardised on the data, and drag is not modelled.

Scaling: pwm⁵ in µs reaches 2·10¹⁶, so the basis uses the PWM as the
normalised actuator output u = (pwm − PWM_OFFSET) / PWM_RANGE with
PWM_OFFSET = 1000 µs, PWM_RANGE = 1000 µs: the fixed PWM_MIN/PWM_MAX map
of the autopilot (u = 0 at the ESC minimum, 1 at its maximum; hover ≈ 0.5).
This is a fixed, data-independent unit change, not a centring: u stays far
from 0 over the flight (0.38 … 0.72), so 1, u, …, u⁵ are strongly
collinear and the constant competes with the linear term exactly as in
the paper's raw-PWM flight. ``build(pwm_offset=0)`` gives u = pwm / 1000
(milliseconds), the pure scale; see the benchmark for what changes then.

With the simulator's thrust a_T = THRUST_GAIN·(pwm − 1000 µs) the truth in
this basis is w_u = 2 g = 19.62 and all other weights 0, up to the tilt
(cos ≤ 1), which the model leaves out; the simulator's rotor drag acts in the
rotor plane, not along z. ``build(drag=True)`` adds the candidate ``drag_lin``
(−v_z) for flights with an axial drag (``quadrotor_sim.vertical(seed,
axial_drag=0.3)``: truth 0.3), which the paper's basis cannot represent.
"""
import numpy as np

from skigen import Model
from skigen.library import term

from . import quadrotor_sim as sim

DT = sim.VERTICAL["dt"]               # s (100 Hz)
NOISE_STD = sim.NOISE_STD             # m
PWM_OFFSET = 1000.0                   # µs (the autopilot's PWM_MIN)
PWM_RANGE = 1000.0                    # µs (PWM_MAX − PWM_MIN)
DEGREE = 5
TERMS = ["1", "pwm"] + [f"pwm^{k}" for k in range(2, DEGREE + 1)]
TRUE_TERM = "pwm"
DRAG_RMS = 0.676                      # m/s: RMS of v_z over the vertical flight with axial drag 0.3 (seed 0)


def w_true(pwm_offset=PWM_OFFSET, pwm_range=PWM_RANGE) -> np.ndarray:
    """The simulator's thrust law a_T = c (pwm − 1000) in the basis 1, u, …, u⁵."""
    c = sim.THRUST_GAIN
    return np.array([c * (pwm_offset - sim.PWM_MIN), c * pwm_range, 0, 0, 0, 0])


W_TRUE = w_true()
# RMS of uᵏ over the vertical flight (seed 0), the scale-aware prior's PRIOR_ACCEL (m/s²,
# as for the spiral) and the process noise rule of the spiral (gust σ·sqrt(2 τ dt)).
BASIS_RMS = np.array([1.0, 0.707, 0.505, 0.365, 0.266, 0.196])
PRIOR_ACCEL = 1.0
PRIOR_VARIANCE = (PRIOR_ACCEL / BASIS_RMS) ** 2
PROCESS_STD = (1e-4, float(sim.GUST_STD * np.sqrt(2 * sim.GUST_TAU * DT)))


def basis_rms(pwm, pwm_offset=PWM_OFFSET, pwm_range=PWM_RANGE) -> np.ndarray:
    """RMS of each candidate uᵏ over a flight's PWM."""
    u = (np.asarray(pwm, float) - pwm_offset) / pwm_range
    return np.sqrt(np.mean(u[:, None] ** np.arange(DEGREE + 1), axis=0))


def build(prior_variance=PRIOR_VARIANCE, process_std=PROCESS_STD, weight_std=0.0, initial=1.5,
          position_std=0.1, velocity_std=0.5, pwm_offset=PWM_OFFSET, pwm_range=PWM_RANGE,
          name="quadrotor_vertical", drag=False):
    """The vertical model. process_std: (position m, velocity m/s) per sample. drag: add the
    candidate drag_lin (−v_z) after the powers; its prior variance is then prior_variance's last
    entry (default (PRIOR_ACCEL / DRAG_RMS)²)."""
    model = Model(name, dt=DT, discretization="rk4")
    z = model.state("pz", unit="m", role="position", initial=initial, std=position_std,
                    process_std=process_std[0])
    vz = model.state("vz", unit="m/s", role="velocity", std=velocity_std, process_std=process_std[1])
    pwm = model.input("pwm", unit="us")
    model.dynamics({z: vz, vz: -sim.G})
    model.output("z", z, unit="m", noise_std=NOISE_STD)
    u = (pwm - pwm_offset) / pwm_range
    basis = [term("1", 1, key="one"), term("pwm", u, key="pwm")]
    basis += [term(f"pwm^{k}", u ** k, key=f"pwm{k}") for k in range(2, DEGREE + 1)]
    if drag:
        basis.append(term("drag_lin", -vz, key="drag_lin"))
        if prior_variance is PRIOR_VARIANCE:
            prior_variance = np.r_[PRIOR_VARIANCE, (PRIOR_ACCEL / DRAG_RMS) ** 2]
    model.unknown(vz, basis, prior_variance=prior_variance, process_std=weight_std)
    return model


def recording(flight):
    """A simulated vertical flight as a recording: PWM in, measured height out."""
    from skigen.recording import Recording
    return Recording("quadrotor vertical simulation", flight.t, flight.pwm[:, None].copy(),
                     flight.meas[:, 2:3].copy(), ("pwm",), ("z",))


model = build()
