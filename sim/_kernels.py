"""Compiled step loops of the plants (numba).

Every plant here is linear between events, so a step is the exact matrix
exponential of an augmented system ``z' = M z`` whose state carries the plant
state, the input generator and a constant 1:

    z = [x..., w1, w2, 1]

Sine input (``omega > 0``): ``w1 = sin(omega*t)``, ``w2 = cos(omega*t)`` and the
input is ``amplitude * w1``, exact at every instant. Held input (``omega = 0``):
``w1`` is set to the held setpoint at the start of each step and stays there.

The Coulomb oscillator switches between three regimes (sliding forward,
sliding backward, stuck). Velocity zero crossings and break-away instants are
located to round-off inside the step from a Taylor expansion of the exact
solution, so the link lands exactly in the stuck state and never chatters.
"""

from __future__ import annotations

import math

import numpy as np

from bodebench.sim._jit import njit

TAYLOR_TERMS = 30  # terms of the local expansion; exact to round-off for |M|*tau <= 2
MAX_EVENTS_PER_STEP = 64

# indices into the Coulomb augmented state z = [Y, V, w1, w2, 1]
_Y, _V, _W1, _W2, _ONE = 0, 1, 2, 3, 4


@njit(cache=True)
def expm_small(a: np.ndarray) -> np.ndarray:
    """exp(a) of a small square matrix: Taylor series on a / 2**s with |a / 2**s|_inf <= 2, then s squarings.

    Thirty terms leave a truncation below 1e-23 at that norm; few squarings keep the rounding error near scipy's
    Pade routine. For the plants' matrices (a few states) this costs microseconds where a general routine costs far
    more.
    """
    n = a.shape[0]
    norm = 0.0
    for r in range(n):
        row = 0.0
        for c in range(n):
            row += abs(a[r, c])
        norm = max(norm, row)
    s = 0
    while norm > 2.0:
        norm *= 0.5
        s += 1
    scaled = a / (2.0 ** s)
    result = np.eye(n)
    term = np.eye(n)
    for k in range(1, 31):
        term = term @ scaled / k
        result += term
    for _ in range(s):
        result = result @ result
    return result


@njit(cache=True)
def lti_run(phi: np.ndarray, z0: np.ndarray, n_steps: int, held: np.ndarray,
            c_out: np.ndarray, out: np.ndarray) -> None:
    """Advance ``z <- phi @ z`` for n_steps and store the outputs ``c_out @ z``.

    phi: (n, n) exact one-step transition of the augmented system; z0: (n,)
    state, updated in place; held: setpoints per step (length n_steps) written
    into z[-3] before each step, or empty for a sine input; c_out: (n_out, n);
    out: (n_steps, n_out) receives the outputs at the end of each step.
    """
    n = z0.shape[0]
    z = z0
    tmp = np.empty(n)
    use_held = held.shape[0] > 0
    for j in range(n_steps):
        if use_held:
            z[n - 3] = held[j]
        for r in range(n):
            acc = 0.0
            for c in range(n):
                acc += phi[r, c] * z[c]
            tmp[r] = acc
        for r in range(n):
            z[r] = tmp[r]
        for o in range(c_out.shape[0]):
            acc = 0.0
            for c in range(n):
                acc += c_out[o, c] * z[c]
            out[j, o] = acc


@njit(cache=True)
def _powers(m: np.ndarray, z: np.ndarray, pw: np.ndarray) -> None:
    """pw[k] = M^k z / k! for k = 0..TAYLOR_TERMS-1."""
    n = z.shape[0]
    for r in range(n):
        pw[0, r] = z[r]
    for k in range(1, pw.shape[0]):
        for r in range(n):
            acc = 0.0
            for c in range(n):
                acc += m[r, c] * pw[k - 1, c]
            pw[k, r] = acc / k


@njit(cache=True)
def _poly(pw: np.ndarray, row: int, tau: float) -> float:
    """Component ``row`` of exp(M tau) z from the scaled powers (Horner)."""
    acc = 0.0
    for k in range(pw.shape[0] - 1, -1, -1):
        acc = acc * tau + pw[k, row]
    return acc


@njit(cache=True)
def _poly_deriv(pw: np.ndarray, row: int, tau: float) -> float:
    """d/dtau of component ``row`` of exp(M tau) z."""
    acc = 0.0
    for k in range(pw.shape[0] - 1, 0, -1):
        acc = acc * tau + k * pw[k, row]
    return acc


@njit(cache=True)
def _root(pw: np.ndarray, row: int, sign: float, lo: float, hi: float, deriv: bool) -> float:
    """Root of sign*f in [lo, hi] where sign*f(lo) > 0 >= sign*f(hi).

    f is component ``row`` of exp(M tau) z, or its derivative when ``deriv``.
    Newton steps safeguarded by bisection; converges to round-off.
    """
    tau = 0.5 * (lo + hi)
    for _ in range(200):
        if deriv:
            f = _poly_deriv(pw, row, tau) * sign
            df = 0.0
            for k in range(pw.shape[0] - 1, 1, -1):
                df = df * tau + k * (k - 1) * pw[k, row]
            df *= sign
        else:
            f = _poly(pw, row, tau) * sign
            df = _poly_deriv(pw, row, tau) * sign
        if f > 0.0:
            lo = tau
        else:
            hi = tau
        if hi - lo <= 4e-16 * max(hi, 1e-300):
            break
        step_ok = False
        if df != 0.0:
            cand = tau - f / df
            if lo < cand < hi:
                tau = cand
                step_ok = True
        if not step_ok:
            tau = 0.5 * (lo + hi)
    return hi


@njit(cache=True)
def _eval_state(pw: np.ndarray, tau: float, z: np.ndarray) -> None:
    for r in range(z.shape[0]):
        z[r] = _poly(pw, r, tau)


@njit(cache=True)
def _first_breakaway(w1: float, w2: float, omega: float, amplitude: float,
                     load: float, friction: float, limit: float) -> tuple[float, float]:
    """First instant in [0, limit] at which |amplitude*w1(t) - load| leaves the friction band.

    w1 = sin(theta), w2 = cos(theta) at tau = 0; theta advances at omega (rad/s).
    Returns (tau, direction) with direction +1/-1, or (inf, 0) when the net
    force stays inside [-friction, friction] up to ``limit``.
    """
    net = amplitude * w1 - load
    if net > friction:
        return 0.0, 1.0
    if net < -friction:
        return 0.0, -1.0
    if omega == 0.0 or amplitude == 0.0:
        return math.inf, 0.0
    theta0 = math.atan2(w1, w2)
    two_pi = 2.0 * math.pi
    best = math.inf
    direction = 0.0
    sa = 1.0 if amplitude > 0.0 else -1.0
    # amplitude*sin(theta) rises through load+friction where sa*sin rises through sa*(load+friction)/|A|
    for level, sgn in ((load + friction, 1.0), (load - friction, -1.0)):
        x = level / amplitude
        if x > 1.0 or x < -1.0:
            continue
        a = math.asin(x)
        # net crossing the band edge outward: for sgn=+1 amplitude*sin increasing, for -1 decreasing
        theta = a if sgn * sa > 0.0 else math.pi - a  # sin increasing through x, else decreasing through it
        d = (theta - theta0) % two_pi
        if d > two_pi - 1e-9:
            d = 0.0
        t = d / omega
        if t < best:
            best = t
            direction = sgn
    if best > limit:
        return math.inf, 0.0
    return best, direction


@njit(cache=True)
def coulomb_run(m_fwd: np.ndarray, m_bwd: np.ndarray, phi_fwd: np.ndarray, phi_bwd: np.ndarray,
                stiffness: float, friction: float, amplitude: float, omega: float,
                z: np.ndarray, mode: np.ndarray, h: float, n_steps: int, substeps: int,
                held: np.ndarray, out: np.ndarray) -> int:
    """Integrate the oscillator with Coulomb friction exactly over n_steps steps of h seconds.

    m_fwd/m_bwd: augmented system matrices while sliding with V > 0 / V < 0;
    phi_*: exp(M * h / substeps). z: [Y, V, w1, w2, 1], updated in place;
    mode[0]: +1 sliding forward, -1 backward, 0 stuck, updated in place.
    held: setpoint per step (empty for a sine input). out: (n_steps, 2)
    receives Y and V at the end of each step. Returns the number of stick
    and reversal events handled.
    """
    hs = h / substeps
    pw = np.empty((TAYLOR_TERMS, 5))
    tmp = np.empty(5)
    use_held = held.shape[0] > 0
    events = 0
    s = mode[0]
    for j in range(n_steps):
        if use_held:
            z[_W1] = held[j]
            z[_W2] = 0.0
        for _sub in range(substeps):
            rem = hs
            n_ev = 0
            while rem > 0.0:
                n_ev += 1
                if n_ev > MAX_EVENTS_PER_STEP:
                    raise RuntimeError("Coulomb link: too many stick/slip events in one step")
                if s == 0.0:
                    load = stiffness * z[_Y]
                    tb, direction = _first_breakaway(z[_W1], z[_W2], omega, amplitude, load, friction, rem)
                    tau = rem if tb == math.inf else tb
                    if tau > 0.0 and omega != 0.0:
                        c = math.cos(omega * tau)
                        sn = math.sin(omega * tau)
                        w1 = z[_W1] * c + z[_W2] * sn
                        w2 = z[_W2] * c - z[_W1] * sn
                        z[_W1] = w1
                        z[_W2] = w2
                    z[_V] = 0.0
                    rem -= tau
                    if tb != math.inf:
                        s = direction
                        events += 1
                        if rem <= 1e-15 * hs:
                            rem = 0.0
                    continue
                mm = m_fwd if s > 0.0 else m_bwd
                full = rem == hs
                if full:
                    ph = phi_fwd if s > 0.0 else phi_bwd
                    for r in range(5):
                        acc = 0.0
                        for c in range(5):
                            acc += ph[r, c] * z[c]
                        tmp[r] = acc
                    v_end = tmp[_V]
                    quick = v_end * s > 0.0 and z[_V] * s > 0.0
                    if quick:
                        # velocity kept its sign at both ends; rule out a dip through zero inside
                        a0 = 0.0
                        a1 = 0.0
                        for c in range(5):
                            a0 += mm[_V, c] * z[c]
                            a1 += mm[_V, c] * tmp[c]
                        if not (a0 * s < 0.0 and a1 * s > 0.0):
                            for r in range(5):
                                z[r] = tmp[r]
                            rem = 0.0
                            continue
                _powers(mm, z, pw)
                v_end = _poly(pw, _V, rem) * s
                v0 = z[_V] * s
                crossing = -1.0
                if v0 > 0.0 and v_end <= 0.0:
                    crossing = _root(pw, _V, s, 0.0, rem, False)
                else:
                    # velocity may leave zero (v0 == 0) or dip (v0 > 0): split at the extremum of V*s
                    a0 = _poly_deriv(pw, _V, 0.0) * s
                    a1 = _poly_deriv(pw, _V, rem) * s
                    if v0 > 0.0 and a0 < 0.0 and a1 > 0.0:
                        tm = _root(pw, _V, -s, 0.0, rem, True)
                        if _poly(pw, _V, tm) * s <= 0.0:
                            crossing = _root(pw, _V, s, 0.0, tm, False)
                    elif v0 == 0.0 and v_end <= 0.0:
                        if a1 < 0.0:
                            lo = 0.0
                            if a0 <= 0.0:
                                lo = rem * 1e-12
                            tm = _root(pw, _V, s, lo, rem, True)
                            crossing = _root(pw, _V, s, tm, rem, False) if _poly(pw, _V, tm) * s > 0.0 else 0.0
                        else:
                            crossing = 0.0
                if crossing < 0.0:
                    _eval_state(pw, rem, z)
                    rem = 0.0
                    continue
                _eval_state(pw, crossing, z)
                z[_V] = 0.0
                rem -= crossing
                if rem <= 1e-15 * hs:
                    rem = 0.0
                events += 1
                net = amplitude * z[_W1] - stiffness * z[_Y]
                if abs(net) <= friction:
                    s = 0.0
                else:
                    new_s = 1.0 if net > 0.0 else -1.0
                    if new_s == s and crossing == 0.0:
                        raise RuntimeError("Coulomb link: velocity cannot leave zero")
                    s = new_s
        out[j, 0] = z[_Y]
        out[j, 1] = z[_V]
    mode[0] = s
    return events
