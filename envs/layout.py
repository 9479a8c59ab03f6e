"""The plant's array layouts: the state (B, NX), the controls (B, NU) and the diagnostics
(B, NAUX), by name and column, and the friction range the plant accepts."""

#: State layout, shape (..., NX): pose, body velocities, wheel speeds, motor torques,
#: steer angles, tyre deflections (relaxed slip * relaxation length), lagged accelerations and
#: the friction brakes' calliper pressures [Pa].
STATE_NAMES = (
    "x",
    "y",
    "psi",
    "u",
    "v",
    "r",
    "omega_fl",
    "omega_fr",
    "omega_rl",
    "omega_rr",
    "torque_fl",
    "torque_fr",
    "torque_rl",
    "torque_rr",
    "delta_f",
    "delta_r",
    "defl_x_fl",
    "defl_x_fr",
    "defl_x_rl",
    "defl_x_rr",
    "defl_y_fl",
    "defl_y_fr",
    "defl_y_rl",
    "defl_y_rr",
    "ax_lag",
    "ay_lag",
    "brake_fl",
    "brake_fr",
    "brake_rl",
    "brake_rr",
)
NX = len(STATE_NAMES)
S_X, S_Y, S_PSI, S_U, S_V, S_R = range(6)
S_OMEGA, S_TORQUE, S_DELTA_F, S_DELTA_R, S_DEFL_X, S_DEFL_Y, S_AX, S_AY, S_BRAKE = 6, 10, 14, 15, 16, 20, 24, 25, 26

#: Control layout, shape (..., NU): motor torque commands [N m], road-wheel steer commands [rad]
#: and brake pressure commands [Pa].
CONTROL_NAMES = (
    "torque_fl",
    "torque_fr",
    "torque_rl",
    "torque_rr",
    "delta_f",
    "delta_r",
    "brake_fl",
    "brake_fr",
    "brake_rl",
    "brake_rr",
)
NU = len(CONTROL_NAMES)
C_TORQUE, C_DELTA_F, C_DELTA_R, C_BRAKE = 0, 4, 5, 6

#: Diagnostic outputs, shape (..., NAUX), evaluated at the returned state:
#:
#: - ax, ay: body specific forces [m/s^2] (what an accelerometer reads: du/dt - r v and dv/dt + r u,
#:   not du/dt), before the load-transfer lag
#: - fz: normal loads [N] (with the lagged load transfer)
#: - fx, fy: tyre forces [N] in each wheel's own frame (rotate by its steer angle for body axes),
#:   including the low-speed damping
#: - kappa: relaxed (transient) longitudinal slip [-], as the tyre sees it
#: - alpha: relaxed (transient) slip angle [rad]
#: - mu: road friction under each wheel [-]
#: - usage: friction used, |F| / (mu Fz) [-]; can exceed 1 where the Magic Formula's peak rises above
#:   mu at light loads (load sensitivity), and in combined slip, whose MF 5.2 weights of Fx and Fy are
#:   independent (1.04 at the reference load at kappa -0.13 and 4.1 deg)
#: - brake_torque: the friction brake's torque [N m], positive against forward spin (at most
#:   brake_gain x pressure; less while it holds a locked wheel)
AUX_NAMES = (
    "ax",
    "ay",
    "fz_fl",
    "fz_fr",
    "fz_rl",
    "fz_rr",
    "fx_fl",
    "fx_fr",
    "fx_rl",
    "fx_rr",
    "fy_fl",
    "fy_fr",
    "fy_rl",
    "fy_rr",
    "kappa_fl",
    "kappa_fr",
    "kappa_rl",
    "kappa_rr",
    "alpha_fl",
    "alpha_fr",
    "alpha_rl",
    "alpha_rr",
    "mu_fl",
    "mu_fr",
    "mu_rl",
    "mu_rr",
    "usage_fl",
    "usage_fr",
    "usage_rl",
    "usage_rr",
    "brake_torque_fl",
    "brake_torque_fr",
    "brake_torque_rl",
    "brake_torque_rr",
)
NAUX = len(AUX_NAMES)
A_AX, A_AY, A_FZ, A_FX, A_FY, A_KAPPA, A_ALPHA, A_MU, A_USAGE, A_BRAKE_TORQUE = 0, 1, 2, 6, 10, 14, 18, 22, 26, 30

MU_MAX = 2.0  #: largest accepted road friction coefficient
