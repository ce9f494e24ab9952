"""Electrohydraulic position drive: position controller, servo valve and cylinder in one plant.

The input is the position setpoint r (m) given to the drive's controller. The plant holds

- the controller's position loop: normalised valve current ``i = clip(K_loop*(r - y), -1, 1)``;
- the servo valve spool (normalised stroke, stops at +-1):
  ``x_v'' = w_v^2 (i - x_v) - 2 zeta_v w_v x_v'``; at a stop the spool is held there and its outward velocity zeroed;
- a critically lapped 4-way valve feeding a symmetric cylinder:
  ``Q_L = K_q x_v sqrt(max(P_s - sign(x_v) P_L, 0) / 2)`` (flow saturates at full spool);
- the load pressure: ``(V_t / (4 beta)) P_L' = Q_L - A_p v - C_l P_L``;
- the piston: ``m v' = A_p P_L - F_c sign(v) - K_load y - b v``, ``y' = v``, with Coulomb friction as true
  stick-slip: while stuck, ``v = 0`` exactly and ``y`` stays put as long as ``|A_p P_L - K_load y| <= F_c``.

Integration: classical fixed-step RK4 (numba) on sub-steps of at most 1/``substeps_per_period`` of the period of
the fastest linearised mode. Friction events are located inside a sub-step: the instant the velocity reaches zero
(then the piston sticks or reverses) and the instant the net force leaves the friction band (break-away) are roots
of the RK4 solution as a function of the step length, found to round-off; a sliding piece whose velocity keeps its
sign at both ends but decelerates then accelerates is searched for a dip through zero. An excursion of the net force
out of the band and back within one stuck sub-step would go unnoticed (sub-steps are short against every mode). The
spool stops are applied after each step (the spool is clipped back to +-1 with its outward velocity zeroed), so
impacts are resolved to one sub-step. With F_c = 0 the piston simply slides (no events).

Outputs, sampled at the end of every step: position y (m), velocity v (m/s), spool x_v (1), load pressure P_L (Pa).
"""

from __future__ import annotations

import math

import numpy as np

from bodebench.sim._jit import njit
from bodebench.sim.plants import LinearPlant, Plant, PlantState

__all__ = ["ElectrohydraulicDrive", "HYDRAULIC_DEFAULTS"]

HYDRAULIC_DEFAULTS: dict[str, float] = {
    "supply_pressure": 210e5,  # Pa (210 bar)
    "valve_gain": 1.8e-7,  # m^3/(s*Pa^0.5): 20 L/min at 70 bar valve drop, 35 L/min no-load at 210 bar
    "valve_natural_frequency_hz": 150.0,  # Hz
    "valve_damping_ratio": 0.7,  # 1
    "piston_area": 5e-4,  # m^2 (10.5 kN stall force at 210 bar)
    "total_volume": 1.5e-4,  # m^3, both chambers and lines
    "bulk_modulus": 1.4e9,  # Pa, effective (oil, hoses)
    "leakage": 2e-12,  # m^3/(s*Pa), cross-port leakage coefficient C_l
    "piston_mass": 40.0,  # kg, piston, rod and moved load
    "load_stiffness": 0.0,  # N/m
    "viscous_damping": 2000.0,  # N*s/m
    "coulomb_friction": 150.0,  # N, seal friction
    "loop_gain": 60.0,  # 1/m: full valve current at 16.7 mm position error
}
"""Default parameters: a ~10 kN industrial cylinder with a 150 Hz servo valve. The hydraulic natural frequency is
77 Hz, the velocity gain K_v = K_loop K_q sqrt(P_s/2)/A_p = 70 1/s, the closed-loop -3 dB bandwidth 13 Hz."""

SUBSTEPS_PER_PERIOD = 40
"""Default RK4 sub-steps per period of the fastest linearised mode."""
MAX_EVENTS_PER_SUBSTEP = 64

# indices of the state vector z = [y, v, P_L, x_v, x_v']
_Y, _V, _P, _X, _U = 0, 1, 2, 3, 4
# indices of the parameter vector
(_PS, _KQ, _WV, _ZV, _AP, _C4, _CL, _M, _KL, _B, _FC, _KLOOP) = range(12)


@njit(cache=True)
def _setpoint(t: float, amplitude: float, omega: float, held: float, use_held: bool) -> float:
    """Setpoint r (m) at time t (s): the held value, or amplitude*sin(omega*t)."""
    if use_held:
        return held
    return amplitude * math.sin(omega * t)


@njit(cache=True)
def _rhs(p: np.ndarray, z: np.ndarray, mode: float, r: float, dz: np.ndarray) -> None:
    """Time derivative of z under setpoint r; mode 0 holds the piston (stuck), +-1 slides with friction -F_c*mode."""
    y = z[_Y]
    v = z[_V]
    pl = z[_P]
    xv = z[_X]
    uv = z[_U]
    cur = p[_KLOOP] * (r - y)
    if cur > 1.0:
        cur = 1.0
    elif cur < -1.0:
        cur = -1.0
    xc = xv
    if xc > 1.0:
        xc = 1.0
    elif xc < -1.0:
        xc = -1.0
    rad = 0.5 * (p[_PS] - pl) if xc >= 0.0 else 0.5 * (p[_PS] + pl)
    if rad < 0.0:
        rad = 0.0
    q = p[_KQ] * xc * math.sqrt(rad)
    dz[_P] = p[_C4] * (q - p[_AP] * v - p[_CL] * pl)
    dz[_X] = uv
    dz[_U] = p[_WV] * p[_WV] * (cur - xv) - 2.0 * p[_ZV] * p[_WV] * uv
    if mode == 0.0:
        dz[_Y] = 0.0
        dz[_V] = 0.0
    else:
        dz[_Y] = v
        dz[_V] = (p[_AP] * pl - p[_KL] * y - p[_B] * v - p[_FC] * mode) / p[_M]


@njit(cache=True)
def _rk4(p: np.ndarray, z: np.ndarray, mode: float, t: float, tau: float, amplitude: float, omega: float,
         held: float, use_held: bool, out: np.ndarray, work: np.ndarray) -> None:
    """One classical RK4 step of length tau (s) from z at time t; result in out. work: (5, 5) scratch."""
    n = z.shape[0]
    k1 = work[0]
    k2 = work[1]
    k3 = work[2]
    k4 = work[3]
    zt = work[4]
    r0 = _setpoint(t, amplitude, omega, held, use_held)
    rm = _setpoint(t + 0.5 * tau, amplitude, omega, held, use_held)
    r1 = _setpoint(t + tau, amplitude, omega, held, use_held)
    _rhs(p, z, mode, r0, k1)
    for c in range(n):
        zt[c] = z[c] + 0.5 * tau * k1[c]
    _rhs(p, zt, mode, rm, k2)
    for c in range(n):
        zt[c] = z[c] + 0.5 * tau * k2[c]
    _rhs(p, zt, mode, rm, k3)
    for c in range(n):
        zt[c] = z[c] + tau * k3[c]
    _rhs(p, zt, mode, r1, k4)
    for c in range(n):
        out[c] = z[c] + tau / 6.0 * (k1[c] + 2.0 * k2[c] + 2.0 * k3[c] + k4[c])


@njit(cache=True)
def _probe(p: np.ndarray, z: np.ndarray, mode: float, t: float, tau: float, amplitude: float, omega: float,
           held: float, use_held: bool, kind: int, tmp: np.ndarray, work: np.ndarray) -> float:
    """Velocity (kind 0) or net force A_p P_L - K_load y (kind 1) after an RK4 step of tau from z."""
    if tau == 0.0:
        for c in range(z.shape[0]):
            tmp[c] = z[c]
    else:
        _rk4(p, z, mode, t, tau, amplitude, omega, held, use_held, tmp, work)
    if kind == 0:
        return tmp[_V]
    return p[_AP] * tmp[_P] - p[_KL] * tmp[_Y]


@njit(cache=True)
def _root(p: np.ndarray, z: np.ndarray, mode: float, t: float, amplitude: float, omega: float, held: float,
          use_held: bool, kind: int, sign: float, offset: float, lo: float, hi: float,
          tmp: np.ndarray, work: np.ndarray) -> float:
    """Step length in [lo, hi] where g(tau) = sign*probe(tau) - offset falls to 0 (g(lo) >= 0 > or = g(hi)).

    Regula falsi with the Illinois modification, safeguarded by bisection; returns the upper end of the final
    bracket, where g <= 0 (the event has happened).
    """
    g_lo = sign * _probe(p, z, mode, t, lo, amplitude, omega, held, use_held, kind, tmp, work) - offset
    g_hi = sign * _probe(p, z, mode, t, hi, amplitude, omega, held, use_held, kind, tmp, work) - offset
    side = 0
    for _ in range(200):
        if hi - lo <= 4e-16 * hi:
            break
        cand = hi - g_hi * (hi - lo) / (g_hi - g_lo) if g_lo > g_hi else 0.5 * (lo + hi)
        if not (lo < cand < hi):
            cand = 0.5 * (lo + hi)
        g = sign * _probe(p, z, mode, t, cand, amplitude, omega, held, use_held, kind, tmp, work) - offset
        if g > 0.0:
            lo = cand
            g_lo = g
            if side == 1:
                g_hi *= 0.5
            side = 1
        else:
            hi = cand
            g_hi = g
            if side == -1:
                g_lo *= 0.5
            side = -1
            if g == 0.0:
                break
    return hi


@njit(cache=True)
def _extremum(p: np.ndarray, z: np.ndarray, mode: float, t: float, amplitude: float, omega: float, held: float,
              use_held: bool, sign: float, lo: float, hi: float, tmp: np.ndarray,
              work: np.ndarray) -> tuple[float, float]:
    """(tau, value) of the minimum of sign*v(tau) on [lo, hi] by golden-section search (unimodal there)."""
    ratio = 0.5 * (math.sqrt(5.0) - 1.0)
    a = lo
    b = hi
    c = b - ratio * (b - a)
    d = a + ratio * (b - a)
    fc = sign * _probe(p, z, mode, t, c, amplitude, omega, held, use_held, 0, tmp, work)
    fd = sign * _probe(p, z, mode, t, d, amplitude, omega, held, use_held, 0, tmp, work)
    for _ in range(80):
        if b - a <= 1e-13 * hi:
            break
        if fc < fd:
            b = d
            d = c
            fd = fc
            c = b - ratio * (b - a)
            fc = sign * _probe(p, z, mode, t, c, amplitude, omega, held, use_held, 0, tmp, work)
        else:
            a = c
            c = d
            fc = fd
            d = a + ratio * (b - a)
            fd = sign * _probe(p, z, mode, t, d, amplitude, omega, held, use_held, 0, tmp, work)
    if fc < fd:
        return c, fc
    return d, fd


@njit(cache=True)
def _spool_stops(z: np.ndarray) -> None:
    """Clip the spool to its stops at +-1 and zero its velocity into the stop."""
    if z[_X] > 1.0:
        z[_X] = 1.0
        if z[_U] > 0.0:
            z[_U] = 0.0
    elif z[_X] < -1.0:
        z[_X] = -1.0
        if z[_U] < 0.0:
            z[_U] = 0.0


@njit(cache=True)
def hydraulic_run(p: np.ndarray, z: np.ndarray, mode: np.ndarray, t_start: float, h: float, n_steps: int,
                  substeps: int, amplitude: float, omega: float, held: np.ndarray, out: np.ndarray) -> int:
    """Integrate the drive over n_steps steps of h seconds from t_start (s).

    p: parameter vector (see ElectrohydraulicDrive._params); z: [y, v, P_L, x_v, x_v'], updated in place;
    mode[0]: +1 / -1 sliding, 0 stuck, updated in place. Setpoint: amplitude*sin(omega*t), or held[j] over step j
    when held is non-empty. out: (n_steps, 4) receives y, v, x_v, P_L at the end of each step. Returns the number
    of stick, reversal and break-away events handled.
    """
    hs = h / substeps
    use_held = held.shape[0] > 0
    friction = p[_FC] > 0.0
    tmp = np.empty(5)  # scratch of the event searches
    end = np.empty(5)  # the state at the end of the current piece
    work = np.empty((5, 5))
    dz = np.empty(5)
    events = 0
    s = mode[0]
    if not friction:
        s = 1.0
    r_held = 0.0
    for j in range(n_steps):
        if use_held:
            r_held = held[j]
        for k in range(substeps):
            t_sub = t_start + j * h + k * hs
            rem = hs
            n_ev = 0
            while rem > 0.0:
                t = t_sub + (hs - rem)
                _spool_stops(z)
                _rk4(p, z, s, t, rem, amplitude, omega, r_held, use_held, end, work)
                if not friction:
                    for c in range(5):
                        z[c] = end[c]
                    rem = 0.0
                    break
                n_ev += 1
                if n_ev > MAX_EVENTS_PER_SUBSTEP:
                    raise RuntimeError("hydraulic drive: too many stick/slip events in one sub-step")
                fc = p[_FC]
                if s == 0.0:
                    load = p[_KL] * z[_Y]
                    f1 = p[_AP] * end[_P] - load
                    if abs(f1) <= fc:
                        for c in range(5):
                            z[c] = end[c]
                        z[_V] = 0.0
                        rem = 0.0
                        continue
                    direction = 1.0 if f1 > 0.0 else -1.0
                    f0 = p[_AP] * z[_P] - load
                    tb = 0.0
                    if direction * f0 <= fc:
                        # g = F_c - direction*F falls through zero at break-away
                        tb = _root(p, z, 0.0, t, amplitude, omega, r_held, use_held, 1, -direction, -fc,
                                   0.0, rem, tmp, work)
                        _rk4(p, z, 0.0, t, tb, amplitude, omega, r_held, use_held, tmp, work)
                        for c in range(5):
                            z[c] = tmp[c]
                        z[_V] = 0.0
                    s = direction
                    events += 1
                    rem -= tb
                    if rem <= 1e-15 * hs:
                        rem = 0.0
                    continue
                v0 = s * z[_V]
                v1 = s * end[_V]
                crossing = -1.0
                if v0 > 0.0 and v1 <= 0.0:
                    crossing = _root(p, z, s, t, amplitude, omega, r_held, use_held, 0, s, 0.0, 0.0, rem, tmp, work)
                elif v0 > 0.0:
                    # both ends moving: look for a dip through zero when the motion decelerates then accelerates
                    _rhs(p, z, s, _setpoint(t, amplitude, omega, r_held, use_held), dz)
                    a0 = s * dz[_V]
                    _rhs(p, end, s, _setpoint(t + rem, amplitude, omega, r_held, use_held), dz)
                    a1 = s * dz[_V]
                    if a0 < 0.0 and a1 > 0.0:
                        tm, vm = _extremum(p, z, s, t, amplitude, omega, r_held, use_held, s, 0.0, rem, tmp, work)
                        if vm <= 0.0:
                            crossing = _root(p, z, s, t, amplitude, omega, r_held, use_held, 0, s, 0.0, 0.0, tm,
                                             tmp, work)
                elif v1 <= 0.0:
                    # just broken away (v0 == 0) and not moving forward at the end: find the forward excursion
                    tm, vm = _extremum(p, z, s, t, amplitude, omega, r_held, use_held, -s, 0.0, rem, tmp, work)
                    if -vm > 0.0:
                        crossing = _root(p, z, s, t, amplitude, omega, r_held, use_held, 0, s, 0.0, tm, rem,
                                         tmp, work)
                    else:
                        crossing = 0.0
                if crossing < 0.0:
                    for c in range(5):
                        z[c] = end[c]
                    rem = 0.0
                    continue
                if crossing > 0.0:
                    _rk4(p, z, s, t, crossing, amplitude, omega, r_held, use_held, tmp, work)
                    for c in range(5):
                        z[c] = tmp[c]
                z[_V] = 0.0
                rem -= crossing
                if rem <= 1e-15 * hs:
                    rem = 0.0
                events += 1
                net = p[_AP] * z[_P] - p[_KL] * z[_Y]
                # stuck (a zero-length excursion means the force only grazed the band edge), else sliding with net
                stuck = abs(net) <= fc or crossing == 0.0
                s = 0.0 if stuck else (1.0 if net > 0.0 else -1.0)
            _spool_stops(z)
        out[j, 0] = z[_Y]
        out[j, 1] = z[_V]
        out[j, 2] = z[_X]
        out[j, 3] = z[_P]
    mode[0] = s
    return events


def _check_positive(name: str, value: float, allow_zero: bool = False) -> float:
    value = float(value)
    if not math.isfinite(value) or value < 0.0 or (value == 0.0 and not allow_zero):
        need = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"ElectrohydraulicDrive: {name} must be a finite number {need}, got {value!r}")
    return value


class ElectrohydraulicDrive(Plant):
    """Electrohydraulic position drive (position loop, servo valve, cylinder); input: position setpoint (m).

    Parameters (SI units; defaults in :data:`HYDRAULIC_DEFAULTS`):
        supply_pressure: P_s, Pa (return at 0 Pa).
        valve_gain: K_q, m^3/(s*Pa^0.5); Q_L = K_q x_v sqrt((P_s - sign(x_v) P_L)/2).
        valve_natural_frequency_hz: spool natural frequency f_v = w_v/(2 pi), Hz.
        valve_damping_ratio: spool damping ratio zeta_v, 1.
        piston_area: A_p, m^2 (both sides, symmetric cylinder).
        total_volume: V_t, m^3 (both chambers and lines).
        bulk_modulus: effective beta, Pa.
        leakage: C_l, m^3/(s*Pa).
        piston_mass: m, kg (piston, rod and load).
        load_stiffness: K_load, N/m.
        viscous_damping: b, N*s/m.
        coulomb_friction: F_c, N (stick-slip, equal static and sliding levels).
        loop_gain: K_loop, 1/m (valve current per metre of position error, clipped to +-1).
        substeps_per_period: RK4 sub-steps per period of the fastest linearised mode (accuracy knob).
    Outputs: position (m), velocity (m/s), spool (normalised, 1), load_pressure (Pa).
    """

    output_names = ("position", "velocity", "spool", "load_pressure")

    def __init__(self, supply_pressure: float = HYDRAULIC_DEFAULTS["supply_pressure"],
                 valve_gain: float = HYDRAULIC_DEFAULTS["valve_gain"],
                 valve_natural_frequency_hz: float = HYDRAULIC_DEFAULTS["valve_natural_frequency_hz"],
                 valve_damping_ratio: float = HYDRAULIC_DEFAULTS["valve_damping_ratio"],
                 piston_area: float = HYDRAULIC_DEFAULTS["piston_area"],
                 total_volume: float = HYDRAULIC_DEFAULTS["total_volume"],
                 bulk_modulus: float = HYDRAULIC_DEFAULTS["bulk_modulus"],
                 leakage: float = HYDRAULIC_DEFAULTS["leakage"],
                 piston_mass: float = HYDRAULIC_DEFAULTS["piston_mass"],
                 load_stiffness: float = HYDRAULIC_DEFAULTS["load_stiffness"],
                 viscous_damping: float = HYDRAULIC_DEFAULTS["viscous_damping"],
                 coulomb_friction: float = HYDRAULIC_DEFAULTS["coulomb_friction"],
                 loop_gain: float = HYDRAULIC_DEFAULTS["loop_gain"],
                 substeps_per_period: int = SUBSTEPS_PER_PERIOD) -> None:
        self.supply_pressure = _check_positive("supply_pressure", supply_pressure)
        self.valve_gain = _check_positive("valve_gain", valve_gain)
        self.valve_natural_frequency_hz = _check_positive("valve_natural_frequency_hz", valve_natural_frequency_hz)
        self.valve_damping_ratio = _check_positive("valve_damping_ratio", valve_damping_ratio, allow_zero=True)
        self.piston_area = _check_positive("piston_area", piston_area)
        self.total_volume = _check_positive("total_volume", total_volume)
        self.bulk_modulus = _check_positive("bulk_modulus", bulk_modulus)
        self.leakage = _check_positive("leakage", leakage, allow_zero=True)
        self.piston_mass = _check_positive("piston_mass", piston_mass)
        self.load_stiffness = _check_positive("load_stiffness", load_stiffness, allow_zero=True)
        self.viscous_damping = _check_positive("viscous_damping", viscous_damping, allow_zero=True)
        self.coulomb_friction = _check_positive("coulomb_friction", coulomb_friction, allow_zero=True)
        self.loop_gain = _check_positive("loop_gain", loop_gain)
        if isinstance(substeps_per_period, bool) or not isinstance(substeps_per_period, int) \
                or substeps_per_period < 8:
            raise ValueError(f"ElectrohydraulicDrive: substeps_per_period must be an integer >= 8, "
                             f"got {substeps_per_period!r}")
        self.substeps_per_period = substeps_per_period
        self._params = np.array([
            self.supply_pressure, self.valve_gain, 2.0 * math.pi * self.valve_natural_frequency_hz,
            self.valve_damping_ratio, self.piston_area, 4.0 * self.bulk_modulus / self.total_volume,
            self.leakage, self.piston_mass, self.load_stiffness, self.viscous_damping, self.coulomb_friction,
            self.loop_gain,
        ])
        lin = self.linearized()
        rates = [float(np.max(np.abs(np.linalg.eigvals(lin.a)))), 2.0 * math.pi * self.natural_frequency_hz,
                 2.0 * math.pi * self.valve_natural_frequency_hz]
        self.max_substep = 2.0 * math.pi / (max(rates) * substeps_per_period)
        """Longest RK4 sub-step, s."""
        self.events = 0  # stick, reversal and break-away events handled so far

    @property
    def natural_frequency_hz(self) -> float:
        """Hydraulic natural frequency sqrt((4 beta A_p^2 / V_t + K_load) / m) / (2 pi), Hz."""
        k_h = 4.0 * self.bulk_modulus * self.piston_area ** 2 / self.total_volume
        return math.sqrt((k_h + self.load_stiffness) / self.piston_mass) / (2.0 * math.pi)

    @property
    def max_velocity(self) -> float:
        """No-load velocity at full spool, K_q sqrt(P_s/2) / A_p, m/s."""
        return self.valve_gain * math.sqrt(0.5 * self.supply_pressure) / self.piston_area

    @property
    def velocity_gain(self) -> float:
        """Small-signal position-loop gain K_v = K_loop K_q sqrt(P_s/2) / A_p, 1/s."""
        return self.loop_gain * self.max_velocity

    def linearized(self) -> LinearPlant:
        """The small-signal model about rest (P_L = 0, x_v = 0), friction left out, as a LinearPlant.

        State [y, v, P_L, x_v, x_v'], input the setpoint, outputs as :attr:`output_names`.
        """
        wv = 2.0 * math.pi * self.valve_natural_frequency_hz
        c4 = 4.0 * self.bulk_modulus / self.total_volume
        kqv = self.valve_gain * math.sqrt(0.5 * self.supply_pressure)
        m = self.piston_mass
        a = np.array([
            [0.0, 1.0, 0.0, 0.0, 0.0],
            [-self.load_stiffness / m, -self.viscous_damping / m, self.piston_area / m, 0.0, 0.0],
            [0.0, -c4 * self.piston_area, -c4 * self.leakage, c4 * kqv, 0.0],
            [0.0, 0.0, 0.0, 0.0, 1.0],
            [-wv * wv * self.loop_gain, 0.0, 0.0, -wv * wv, -2.0 * self.valve_damping_ratio * wv],
        ])
        b = np.array([0.0, 0.0, 0.0, 0.0, wv * wv * self.loop_gain])
        c = np.zeros((4, 5))
        c[0, _Y] = c[1, _V] = c[2, _X] = c[3, _P] = 1.0
        return LinearPlant(a, b, c, self.output_names)

    def substeps(self, h: float) -> int:
        """RK4 sub-steps per step of h seconds."""
        return max(1, math.ceil(h / self.max_substep))

    def initial_state(self) -> PlantState:
        """At rest at zero setpoint; stuck when there is friction."""
        return PlantState(np.zeros(5), 0.0 if self.coulomb_friction > 0.0 else 1.0)

    def _run(self, state: PlantState, t_start: float, h: float, n_steps: int, amplitude: float, omega: float,
             held: np.ndarray) -> np.ndarray:
        if not (math.isfinite(h) and h > 0.0):
            raise ValueError(f"ElectrohydraulicDrive: step h must be a finite number > 0 s, got {h!r}")
        if n_steps < 0:
            raise ValueError(f"ElectrohydraulicDrive: n_steps must be >= 0, got {n_steps!r}")
        if state.x.shape != (5,):
            raise ValueError(f"ElectrohydraulicDrive: state vector must have 5 entries, got shape {state.x.shape}")
        z = np.ascontiguousarray(state.x, dtype=float).copy()
        mode = np.array([float(state.mode)])
        if z[_V] != 0.0:
            mode[0] = math.copysign(1.0, z[_V])
        out = np.empty((n_steps, 4))
        self.events += hydraulic_run(self._params, z, mode, float(t_start), float(h), int(n_steps),
                                     self.substeps(h), float(amplitude), float(omega), held, out)
        state.x[:] = z
        state.mode = float(mode[0])
        return out

    def run_sine(self, state: PlantState, t_start: float, h: float, n_steps: int,
                 amplitude: float, frequency_hz: float) -> np.ndarray:
        empty = np.empty(0)
        return self._run(state, t_start, h, n_steps, amplitude, 2.0 * math.pi * frequency_hz, empty)

    def run_held(self, state: PlantState, setpoints: np.ndarray, h: float) -> np.ndarray:
        setpoints = np.ascontiguousarray(setpoints, dtype=float).reshape(-1)
        if setpoints.size == 0:
            return np.empty((0, 4))
        return self._run(state, 0.0, h, setpoints.size, 0.0, 0.0, setpoints)
