"""Simulated plants: the second-order link with Coulomb friction, a linear
oscillator and a first-order lag (docs/METHOD.md section 2).

Every plant advances exactly (to round-off) under either input the instrument
produces:

- ``run_sine``: the excitation ``U = amplitude * sin(2*pi*f*t)`` evaluated
  continuously inside each step (the offline experiment, step
  ``h = 1/(K_f*f)``);
- ``run_held``: one setpoint per step, held constant across it (a servo
  controller stepping at its control rate).

Both return the outputs sampled at the end of every step, so the same plant
object serves the offline experiment and the simulated servo controller.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from bodebench.sim import _kernels

__all__ = ["Plant", "PlantState", "CoulombOscillator", "LinearPlant", "LinearOscillator", "FirstOrderLag"]

_EMPTY = np.empty(0)


@dataclass
class PlantState:
    """Integrator state of a plant: its state vector and a discrete mode (sticking regime)."""

    x: np.ndarray
    mode: float = 0.0

    def copy(self) -> PlantState:
        """An independent copy."""
        return PlantState(self.x.copy(), self.mode)


_CACHE_SIZE = 64  # transition matrices kept per plant (one per distinct step and input)


def _substeps(m: np.ndarray, h: float) -> int:
    """Sub-steps that keep |lambda|*h_sub <= 1 for every eigenvalue of m (local expansions stay exact)."""
    rate = float(np.max(np.abs(np.linalg.eigvals(m)))) if m.size else 0.0
    return max(1, math.ceil(rate * h))


class Plant(ABC):
    """A single-input plant with named outputs, integrated exactly between samples."""

    output_names: tuple[str, ...]

    @abstractmethod
    def initial_state(self) -> PlantState:
        """The plant at rest at zero input."""

    @abstractmethod
    def run_sine(self, state: PlantState, t_start: float, h: float, n_steps: int,
                 amplitude: float, frequency_hz: float) -> np.ndarray:
        """Advance ``state`` (in place) under ``amplitude*sin(2*pi*f*t)`` from t_start (s) by n_steps steps of h (s).

        Returns the outputs at ``t_start + h*j``, j = 1..n_steps, shape (n_steps, len(output_names)).
        """

    @abstractmethod
    def run_held(self, state: PlantState, setpoints: np.ndarray, h: float) -> np.ndarray:
        """Advance ``state`` (in place) by one step of h (s) per setpoint, each held over its step.

        Returns the outputs at the end of each step, shape (len(setpoints), len(output_names)).
        """

    @property
    def natural_frequency_hz(self) -> float | None:
        """Undamped natural frequency (Hz) where the plant has one."""
        return None


def _exosystem_matrix(a: np.ndarray, b: np.ndarray, amplitude: float, omega: float,
                      constant: np.ndarray | None = None) -> np.ndarray:
    """Augmented matrix for z = [x, w1, w2, 1] with input amplitude*w1 and w = (sin, cos) at omega (rad/s)."""
    n = a.shape[0]
    m = np.zeros((n + 3, n + 3))
    m[:n, :n] = a
    m[:n, n] = b * amplitude
    if constant is not None:
        m[:n, n + 2] = constant
    m[n, n + 1] = omega
    m[n + 1, n] = -omega
    return m


class LinearPlant(Plant):
    """Linear state-space plant ``x' = A x + B u``, outputs ``y = C x`` (exact discretisation)."""

    def __init__(self, a: ArrayLike, b: ArrayLike, c: ArrayLike, output_names: tuple[str, ...]) -> None:
        self.a = np.atleast_2d(np.asarray(a, dtype=float))
        self.b = np.asarray(b, dtype=float).reshape(-1)
        self.c = np.atleast_2d(np.asarray(c, dtype=float))
        n = self.a.shape[0]
        if self.a.shape != (n, n) or self.b.shape != (n,) or self.c.shape[1] != n:
            raise ValueError("LinearPlant: A must be (n, n), B (n,), C (n_out, n)")
        if self.c.shape[0] != len(output_names):
            raise ValueError("LinearPlant: one output name per row of C")
        self.output_names = tuple(output_names)
        self._c_aug = np.zeros((self.c.shape[0], n + 3))
        self._c_aug[:, :n] = self.c
        self._cache: dict[tuple[float, float, float], np.ndarray] = {}

    def initial_state(self) -> PlantState:
        return PlantState(np.zeros(self.a.shape[0]))

    def _run(self, state: PlantState, amplitude: float, omega: float, h: float, z: np.ndarray,
             held: np.ndarray, n_steps: int) -> np.ndarray:
        key = (amplitude, omega, h)
        phi = self._cache.get(key)
        if phi is None:
            if len(self._cache) >= _CACHE_SIZE:
                self._cache.clear()
            phi = self._cache[key] = _kernels.expm_small(_exosystem_matrix(self.a, self.b, amplitude, omega) * h)
        out = np.empty((n_steps, self.c.shape[0]))
        _kernels.lti_run(phi, z, n_steps, held, self._c_aug, out)
        state.x[:] = z[: self.a.shape[0]]
        return out

    def run_sine(self, state: PlantState, t_start: float, h: float, n_steps: int,
                 amplitude: float, frequency_hz: float) -> np.ndarray:
        omega = 2.0 * math.pi * frequency_hz
        phase = omega * t_start
        z = np.concatenate([state.x, [math.sin(phase), math.cos(phase), 1.0]])
        return self._run(state, amplitude, omega, h, z, _EMPTY, n_steps)

    def run_held(self, state: PlantState, setpoints: np.ndarray, h: float) -> np.ndarray:
        setpoints = np.ascontiguousarray(setpoints, dtype=float)
        z = np.concatenate([state.x, [0.0, 0.0, 1.0]])
        return self._run(state, 1.0, 0.0, h, z, setpoints, len(setpoints))

    def frequency_response(self, frequency_hz: np.ndarray | float) -> np.ndarray:
        """Exact complex transfer function C (jwI - A)^-1 B of each output at f (Hz): shape (..., n_out)."""
        f = np.atleast_1d(np.asarray(frequency_hz, dtype=float))
        n = self.a.shape[0]
        g = np.empty((f.size, self.c.shape[0]), dtype=complex)
        for i, fi in enumerate(f):
            g[i] = self.c @ np.linalg.solve(2j * math.pi * fi * np.eye(n) - self.a, self.b)
        return g.reshape(np.shape(frequency_hz) + (self.c.shape[0],))


class LinearOscillator(LinearPlant):
    """``m Y'' + c Y' + K_p Y = U`` with ``c = 2 zeta sqrt(K_p m)``; outputs position Y and velocity V.

    damping_ratio 0 is the conservative link, whose transient never decays.
    """

    def __init__(self, mass: float, stiffness: float, damping_ratio: float = 0.0) -> None:
        self.mass, self.stiffness, self.damping_ratio = mass, stiffness, damping_ratio
        c = 2.0 * damping_ratio * math.sqrt(stiffness * mass)
        super().__init__([[0.0, 1.0], [-stiffness / mass, -c / mass]], [0.0, 1.0 / mass],
                         [[1.0, 0.0], [0.0, 1.0]], ("position", "velocity"))

    @property
    def natural_frequency_hz(self) -> float:
        return math.sqrt(self.stiffness / self.mass) / (2.0 * math.pi)


class FirstOrderLag(LinearPlant):
    """``T y' + y = K u``: time constant T (s), static gain K; output y."""

    def __init__(self, time_constant: float, gain: float = 1.0) -> None:
        self.time_constant, self.gain = time_constant, gain
        super().__init__([[-1.0 / time_constant]], [gain / time_constant], [[1.0]], ("position",))


class ProportionalValve(LinearPlant):
    """A proportional valve's spool in its position loop: ``x'' = w_v^2 (u - x) - 2 zeta_v w_v x'``, input the spool
    set point u, output the spool position x (both in the set point's units, % of stroke on a CiA 408 valve);
    natural frequency ``valve_natural_frequency_hz`` (w_v / 2 pi), damping ratio ``valve_damping_ratio``."""

    def __init__(self, valve_natural_frequency_hz: float, valve_damping_ratio: float) -> None:
        self.valve_natural_frequency_hz, self.valve_damping_ratio = valve_natural_frequency_hz, valve_damping_ratio
        w = 2.0 * math.pi * valve_natural_frequency_hz
        super().__init__([[0.0, 1.0], [-w * w, -2.0 * valve_damping_ratio * w]], [0.0, w * w],
                         [[1.0, 0.0]], ("spool",))

    @property
    def natural_frequency_hz(self) -> float:
        return self.valve_natural_frequency_hz


_CoulombMatrices = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]
"""Augmented matrices sliding forward and backward, their one-sub-step transitions, and the sub-steps per step."""


class CoulombOscillator(Plant):
    """Second-order link with classical dry (Coulomb) friction (docs/METHOD.md section 2).

    ``m Y'' = U - F_ct sign(V) - K_p Y - c V`` while sliding; stuck (V = 0
    exactly) while ``|U - K_p Y| <= F_ct``; breaks away the instant the net
    force leaves the friction band. ``c = 2 zeta sqrt(K_p m)`` is an optional
    viscous term (zero in the papers). Outputs: position Y, velocity V.
    """

    output_names = ("position", "velocity")

    def __init__(self, mass: float, stiffness: float, friction: float, damping_ratio: float = 0.0) -> None:
        if mass <= 0 or stiffness <= 0 or friction < 0 or damping_ratio < 0:
            raise ValueError("CoulombOscillator: need mass > 0, stiffness > 0, friction >= 0, damping_ratio >= 0")
        self.mass, self.stiffness, self.friction, self.damping_ratio = mass, stiffness, friction, damping_ratio
        self._damping = 2.0 * damping_ratio * math.sqrt(stiffness * mass)
        self._a = np.array([[0.0, 1.0], [-stiffness / mass, -self._damping / mass]])
        self._b = np.array([0.0, 1.0 / mass])
        self.events = 0  # stick, break-away and reversal events handled so far
        self._cache: dict[tuple[float, float, float], _CoulombMatrices] = {}

    @property
    def natural_frequency_hz(self) -> float:
        return math.sqrt(self.stiffness / self.mass) / (2.0 * math.pi)

    def initial_state(self) -> PlantState:
        return PlantState(np.zeros(2), 0.0)

    def _matrices(self, amplitude: float, omega: float, h: float) -> _CoulombMatrices:
        """Augmented matrices and one-sub-step transitions for sliding forward/backward, cached per step."""
        key = (amplitude, omega, h)
        found = self._cache.get(key)
        if found is None:
            fric = self.friction / self.mass
            m_fwd = _exosystem_matrix(self._a, self._b, amplitude, omega, np.array([0.0, -fric]))
            m_bwd = _exosystem_matrix(self._a, self._b, amplitude, omega, np.array([0.0, fric]))
            sub = _substeps(m_fwd[:4, :4], h)
            found = (m_fwd, m_bwd, _kernels.expm_small(m_fwd * (h / sub)), _kernels.expm_small(m_bwd * (h / sub)), sub)
            if len(self._cache) >= _CACHE_SIZE:
                self._cache.clear()
            self._cache[key] = found
        return found

    def _run(self, state: PlantState, amplitude: float, omega: float, h: float, w: tuple[float, float],
             held: np.ndarray, n_steps: int) -> np.ndarray:
        m_fwd, m_bwd, phi_fwd, phi_bwd, sub = self._matrices(amplitude, omega, h)
        y, v = state.x
        z = np.array([y, v, w[0], w[1], 1.0])
        mode = np.array([state.mode])
        if v != 0.0:
            mode[0] = math.copysign(1.0, v)
        out = np.empty((n_steps, 2))
        self.events += _kernels.coulomb_run(m_fwd, m_bwd, phi_fwd, phi_bwd, self.stiffness, self.friction,
                                            amplitude, omega, z, mode, h, n_steps, sub, held, out)
        state.x[:] = z[:2]
        state.mode = float(mode[0])
        return out

    def run_sine(self, state: PlantState, t_start: float, h: float, n_steps: int,
                 amplitude: float, frequency_hz: float) -> np.ndarray:
        omega = 2.0 * math.pi * frequency_hz
        phase = omega * t_start
        return self._run(state, amplitude, omega, h, (math.sin(phase), math.cos(phase)), _EMPTY, n_steps)

    def run_held(self, state: PlantState, setpoints: np.ndarray, h: float) -> np.ndarray:
        setpoints = np.ascontiguousarray(setpoints, dtype=float)
        return self._run(state, 1.0, 0.0, h, (0.0, 0.0), setpoints, len(setpoints))
