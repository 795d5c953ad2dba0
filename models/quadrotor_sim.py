"""Quadrotor truth simulator (NumPy; stands in for the paper's Gazebo/PX4 runs).

Vehicle (world frame, z up)
---------------------------
    ṗ = v
    v̇ = b3 · a_T(pwm) − d1 · (I − b3 b3ᵀ) v + g + w_gust,      g = [0, 0, −9.81] m/s²
    a_T(pwm) = THRUST_GAIN · (pwm − PWM_MIN)        (LINEAR in the mean PWM)

with ``THRUST_GAIN = 2 g / 1000 µs`` (zero thrust at the ESC minimum
1000 µs, hover at 1500 µs, thrust-to-weight 2 at 2000 µs), ``b3 = R(q) e3``
the body z axis in the world frame and linear ROTOR drag ``d1 = DRAG_LIN =
0.3 1/s`` (no quadratic drag). Rotor drag (blade flapping and induced drag)
acts on the velocity in the rotor plane only, as in Gazebo's PX4 motor model
(``gazebo_motor_model``: −|ω| c_d · v⊥, v⊥ the relative air velocity
perpendicular to the rotor axis), which stands behind the paper's flights;
the thrust does not depend on the axial velocity there. ``axial_drag`` adds
a linear drag −d_a (b3·v) b3 along the rotor axis (0 by default: a
what-if for a vehicle whose thrust falls with its climb rate). ``w_gust`` is a small Ornstein–Uhlenbeck
acceleration disturbance (light turbulence: std ``gust_std`` = 0.02 m/s²,
correlation time 1 s, held over each sample), recorded in the truth: it is
the part of the motion no model term explains, so the filters need process
noise on v. Because the controller reacts to it, it is correlated with the
PWM (closed-loop data), which biases the identified PWM gain a little.

Attitude is NOT simulated as rigid-body rotational dynamics: the attitude
loop is modelled as a discrete first-order lag (time constant
``ATT_TAU = 0.1 s``) of roll, pitch and yaw towards the setpoint, updated
once per sample. Attitude and PWM are held constant over each sample
interval (zero-order hold), and over one interval the translational
dynamics are linear with a constant force, so they are integrated EXACTLY
(closed-form exponential of the linear drag). The recorded inputs at sample
k are the ones applied on [t_k, t_k+1).

Controller (PX4-like cascade, run every sample on a noisy state estimate)
-------------------------------------------------------------------------
position P (+ reference velocity feed-forward) → velocity PID (+ reference
acceleration feed-forward; D on the low-pass-filtered derivative of the
velocity estimate) → desired acceleration → thrust vector (tilt limited to
35°) → attitude setpoint (body z along the thrust vector, yaw held) and a
collective thrust = projection of the thrust vector on the CURRENT body z.
The controller converts thrust to PWM with its own, deliberately wrong,
thrust model (hover believed at 1480 µs, gain 10 % low); the velocity
integrators absorb the error. PWM is clipped to [1100, 1900] µs.
The state estimate is the truth plus white noise (0.01 m, 0.03 m/s) — an
EKF2 stand-in; it is what makes the PWM jitter a little, as on a real
vehicle. Gains (PX4 defaults, rounded): position P 0.95 (xy) / 1.0 (z);
velocity P 1.8 / 4.0, I 0.4 / 2.0, D 0.2 / 0.0.

Flights
-------
:func:`spiral`: 50 Hz, 60 s, a spiral climb about the origin whose radius
grows linearly 0.5 → 5 m at a constant period of 10 s, climbing 0.1 m/s
from 1 m. :func:`vertical`: 100 Hz, 40 s, hover at x = y = 0 with a vertical
sinusoid z = 1.5 + 0.5 sin(2π t / 3 s). Both start at rest, level, on the
reference's initial position. Measured: the position, noise 0.02 m per axis.
Every random draw comes from ``numpy.random.default_rng(seed)`` streams, so a
flight is deterministic per seed.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

G = 9.81                       # m/s²
G_VEC = np.array([0.0, 0.0, -G])
PWM_MIN, PWM_MAX = 1000.0, 2000.0   # µs: ESC range (zero thrust at PWM_MIN)
PWM_HOVER = 1500.0             # µs
THRUST_GAIN = 2.0 * G / (PWM_MAX - PWM_MIN)   # m/s² per µs
DRAG_LIN = 0.3                 # 1/s, true linear drag d1 (true quadratic drag d2 = 0)
ATT_TAU = 0.1                  # s, first-order attitude lag
YAW = 0.3                      # rad, held yaw setpoint
NOISE_STD = 0.02               # m, position measurement noise
GUST_STD = 0.02                # m/s², disturbance acceleration std (light turbulence)
GUST_TAU = 1.0                 # s, its correlation time
EST_STD = (0.01, 0.03)         # controller's estimate noise: position m, velocity m/s
MAX_TILT = np.deg2rad(35.0)
PWM_CLIP = (1100.0, 1900.0)
# controller's (wrong) thrust model
CTRL_HOVER = 1480.0
CTRL_GAIN = 0.9 * THRUST_GAIN
GAINS = dict(pos_p=np.array([0.95, 0.95, 1.0]), vel_p=np.array([1.8, 1.8, 4.0]),
             vel_i=np.array([0.4, 0.4, 2.0]), vel_d=np.array([0.2, 0.2, 0.0]),
             d_cutoff_hz=5.0, vel_max=np.array([8.0, 8.0, 3.0]))

SPIRAL = dict(dt=0.02, duration=60.0, r0=0.5, r1=5.0, period=10.0, climb=0.1, z0=1.0)
VERTICAL = dict(dt=0.01, duration=40.0, z0=1.5, amplitude=0.5, period=3.0)


def thrust_acceleration(pwm):
    """True thrust acceleration along body z (m/s²) of the mean PWM (µs)."""
    return THRUST_GAIN * (np.asarray(pwm, float) - PWM_MIN)


@dataclass
class Flight:
    """One simulated flight; arrays have one row per sample t_k = k dt.

    quat/euler/pwm at row k are the inputs applied on [t_k, t_k+1);
    pos/vel the true state at t_k; meas the noisy position measurement.
    """

    t: np.ndarray
    pos: np.ndarray            # (N, 3) true position, m
    vel: np.ndarray            # (N, 3) true velocity, m/s
    euler: np.ndarray          # (N, 3) roll, pitch, yaw (ZYX), rad
    quat: np.ndarray           # (N, 4) qw, qx, qy, qz (body → world)
    pwm: np.ndarray            # (N,) mean PWM, µs
    meas: np.ndarray           # (N, 3) measured position, m
    gust: np.ndarray           # (N, 3) disturbance acceleration applied on [t_k, t_k+1)
    ref: np.ndarray            # (N, 3) reference position
    dt: float
    noise_std: float
    params: dict = field(default_factory=dict)

    @property
    def b3(self) -> np.ndarray:
        """Body z axis in the world frame, (N, 3)."""
        return body_z(self.quat)


def body_z(quat) -> np.ndarray:
    """R(q) e3 for quaternions (…, 4) = [qw, qx, qy, qz]."""
    qw, qx, qy, qz = np.moveaxis(np.asarray(quat, float), -1, 0)
    return np.stack([2 * (qx * qz + qw * qy), 2 * (qy * qz - qw * qx), 1 - 2 * (qx * qx + qy * qy)], -1)


def euler_to_quat(euler) -> np.ndarray:
    """ZYX (roll φ, pitch θ, yaw ψ) → [qw, qx, qy, qz]."""
    r, p, y = np.moveaxis(np.asarray(euler, float) / 2, -1, 0)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.stack([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy], -1)


def spiral_reference(t, r0=0.5, r1=5.0, period=10.0, climb=0.1, z0=1.0, duration=60.0):
    """Position, velocity, acceleration (each (…, 3)) of the spiral climb."""
    t = np.asarray(t, float)
    rd = (r1 - r0) / duration
    r, w = r0 + rd * t, 2 * np.pi / period
    c, s = np.cos(w * t), np.sin(w * t)
    pos = np.stack([r * c, r * s, z0 + climb * t], -1)
    vel = np.stack([rd * c - r * w * s, rd * s + r * w * c, np.full_like(t, climb)], -1)
    acc = np.stack([-2 * rd * w * s - r * w * w * c, 2 * rd * w * c - r * w * w * s, np.zeros_like(t)], -1)
    return pos, vel, acc


def vertical_reference(t, z0=1.5, amplitude=0.5, period=3.0):
    """Hover at x = y = 0 with z = z0 + A sin(2π t / period)."""
    t = np.asarray(t, float)
    w = 2 * np.pi / period
    zero = np.zeros_like(t)
    pos = np.stack([zero, zero, z0 + amplitude * np.sin(w * t)], -1)
    vel = np.stack([zero, zero, amplitude * w * np.cos(w * t)], -1)
    acc = np.stack([zero, zero, -amplitude * w * w * np.sin(w * t)], -1)
    return pos, vel, acc


def exact_step(pos, vel, acc, drag, dt):
    """Exact solution over dt of ṗ = v, v̇ = acc − drag·v with acc constant (drag ≥ 0, 1/s)."""
    if drag == 0.0:
        return pos + vel * dt + acc * dt * dt / 2, vel + acc * dt
    e = np.exp(-drag * dt)
    one = (1 - e) / drag                       # ∫ e^{-d s} ds over [0, dt]
    return pos + vel * one + acc / drag * (dt - one), vel * e + acc * one


def rotor_step(pos, vel, acc, b3, drag, axial_drag, dt):
    """Exact step of ṗ = v, v̇ = acc − drag (I − b3 b3ᵀ) v − axial_drag (b3 b3ᵀ) v, b3 held:
    the two drags act on complementary subspaces, each solved by :func:`exact_step`."""
    along = lambda x: b3 * (x @ b3)
    p_a, v_a = exact_step(along(pos), along(vel), along(acc), axial_drag, dt)
    p_r, v_r = exact_step(pos - along(pos), vel - along(vel), acc - along(acc), drag, dt)
    return p_a + p_r, v_a + v_r


def simulate(reference, dt: float, duration: float, seed: int = 0, *, noise_std: float = NOISE_STD,
             gust_std: float = GUST_STD, drag: float = DRAG_LIN, axial_drag: float = 0.0) -> Flight:
    """Fly ``reference(t) → (pos, vel, acc)`` for ``duration`` s at sample time ``dt``;
    drag, axial_drag: linear drag in the rotor plane and along the rotor axis, 1/s."""
    N = int(round(duration / dt)) + 1
    t = np.arange(N) * dt
    rng_meas, rng_est, rng_gust = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))
    meas_noise = noise_std * rng_meas.standard_normal((N, 3))
    est_noise = np.concatenate([EST_STD[0] * rng_est.standard_normal((N, 3)),
                                EST_STD[1] * rng_est.standard_normal((N, 3))], 1)
    rho = np.exp(-dt / GUST_TAU)
    gust = np.zeros((N, 3))
    g0 = gust_std * rng_gust.standard_normal((N, 3))
    gust[0] = g0[0]
    for k in range(1, N):
        gust[k] = rho * gust[k - 1] + np.sqrt(1 - rho * rho) * g0[k]
    ref_pos, ref_vel, ref_acc = reference(t)

    pos, vel = np.empty((N, 3)), np.empty((N, 3))
    euler, pwm = np.empty((N, 3)), np.empty(N)
    p, v = ref_pos[0].copy(), np.zeros(3)
    att = np.array([0.0, 0.0, YAW])
    integ, dfilt, v_prev = np.zeros(3), np.zeros(3), None
    a_lp = 1 - np.exp(-2 * np.pi * GAINS["d_cutoff_hz"] * dt)
    a_att = 1 - np.exp(-dt / ATT_TAU)
    for k in range(N):
        pos[k], vel[k] = p, v
        p_est, v_est = p + est_noise[k, :3], v + est_noise[k, 3:]
        # position P → velocity setpoint
        v_sp = np.clip(ref_vel[k] + GAINS["pos_p"] * (ref_pos[k] - p_est), -GAINS["vel_max"], GAINS["vel_max"])
        # velocity PID → desired acceleration
        e = v_sp - v_est
        dv = np.zeros(3) if v_prev is None else (v_est - v_prev) / dt
        v_prev = v_est
        dfilt += a_lp * (dv - dfilt)
        acc_sp = ref_acc[k] + GAINS["vel_p"] * e + GAINS["vel_i"] * integ - GAINS["vel_d"] * dfilt
        # thrust vector, tilt limit
        T = acc_sp - G_VEC
        T[2] = max(T[2], 0.3 * G)
        horiz = np.hypot(T[0], T[1])
        if horiz > T[2] * np.tan(MAX_TILT):
            T[:2] *= T[2] * np.tan(MAX_TILT) / horiz
        else:
            integ += e * dt                       # anti-windup: integrate only when not tilt-limited
        b3_sp = T / np.linalg.norm(T)
        # attitude setpoint (yaw held), first-order lag
        cy, sy = np.cos(YAW), np.sin(YAW)
        bx, by = cy * b3_sp[0] + sy * b3_sp[1], -sy * b3_sp[0] + cy * b3_sp[1]   # Rz(−ψ) b3
        sp = np.array([-np.arcsin(np.clip(by, -1, 1)), np.arctan2(bx, b3_sp[2]), YAW])
        att = att + a_att * (sp - att)
        b3 = body_z(euler_to_quat(att))
        # collective thrust along the current body z → PWM through the controller's model
        a_cmd = float(T @ b3)
        pwm[k] = np.clip(CTRL_HOVER + (a_cmd - G) / CTRL_GAIN, *PWM_CLIP)
        euler[k] = att
        acc = b3 * thrust_acceleration(pwm[k]) + G_VEC + gust[k]
        p, v = rotor_step(p, v, acc, b3, drag, axial_drag, dt)
    params = dict(thrust_gain=THRUST_GAIN, pwm_min=PWM_MIN, drag_lin=drag, axial_drag=axial_drag, drag_quad=0.0,
                  g=G,
                  att_tau=ATT_TAU, gust_std=gust_std, gust_tau=GUST_TAU, noise_std=noise_std, dt=dt,
                  duration=duration, seed=seed)
    return Flight(t, pos, vel, euler, euler_to_quat(euler), pwm, pos + meas_noise, gust, ref_pos,
                  dt, noise_std, params)


def spiral(seed: int = 0, **kw) -> Flight:
    """The spiral climb of the paper's section 4.2 (50 Hz, 60 s)."""
    cfg = {**SPIRAL, **{k: kw.pop(k) for k in list(kw) if k in SPIRAL}}
    ref = lambda t: spiral_reference(t, cfg["r0"], cfg["r1"], cfg["period"], cfg["climb"], cfg["z0"],
                                     cfg["duration"])
    return simulate(ref, cfg["dt"], cfg["duration"], seed, **kw)


def vertical(seed: int = 0, **kw) -> Flight:
    """The vertical sinusoid of the paper's section 4.3 (100 Hz)."""
    cfg = {**VERTICAL, **{k: kw.pop(k) for k in list(kw) if k in VERTICAL}}
    ref = lambda t: vertical_reference(t, cfg["z0"], cfg["amplitude"], cfg["period"])
    return simulate(ref, cfg["dt"], cfg["duration"], seed, **kw)
