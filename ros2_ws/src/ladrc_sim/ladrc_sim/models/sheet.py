"""Sheet surface height ``z_sheet(t)`` in mm (Z up), as a sum of profiles (notes §5).

Every profile but the thin-sheet plate depends on time only, so :class:`Sheet` evaluates
their sum for the whole run up front, vectorised (speed). The plate is pushed by the assist
gas with a force that depends on the current gap, so it is stepped per tick.

Profiles (``kind`` in the scenario file):

``flat``      constant height ``height_mm``.
``step``      ``size_mm`` added from ``t_s`` on (notes §5.1 step test).
``sine``      ``amp_mm sin(2 pi f (t - t_start) + phase)`` inside ``[t_start_s, t_end_s)``.
``chirp``     sine of linearly swept frequency ``f0_hz -> f1_hz`` over ``sweep_s`` starting at
              ``t_start_s`` (notes §5.2 item 2, 0-5 Hz), zero outside the sweep.
``square``    ``+-amp_mm`` square wave (``+`` first) inside the window (notes §5.2 item 3).
``triangle``  ``+-amp_mm`` triangle wave (starts at ``-amp``) inside the window (§5.2 item 4).
``waviness``  band-limited random waviness in time: white Gaussian noise through a zero-phase
              Butterworth low-pass (``cutoff_hz``, order 4, ``sosfiltfilt``), mean removed
              and scaled to exactly ``rms_mm`` over the run. A spatial waviness of shortest
              wavelength ``lambda`` at feed speed ``v`` is the same thing with
              ``cutoff_hz = v / lambda``.
``ridge``     tube-ridge crossing (过楞): a raised-cosine bump of ``height_mm`` and duration
              ``width_s`` centred at ``t_s`` (repeated every ``period_s`` for ``count``
              ridges when ``period_s > 0``, one per tube corner); over the bump the
              capacitive feedback gain drops to ``1 - gain_drop`` at the crest (the notes
              mimic the crossing by shrinking the feedback gain, §5.2 item 4).
``plate``     thin sheet lifted by the assist gas (notes §5.3 item 5): a lightly damped
              mass-spring-damper ``y'' + 2 zeta w y' + w^2 y = -a_gas`` with
              ``w = 2 pi natural_freq_hz`` and a downward gas push (as an acceleration)
              ``a_gas = gas_k_mm2_s2 / (max(gap, 0) + gas_g0_mm)`` that falls with the gap,
              on from ``gas_on_s``; an optional kick (``kick_velocity_mm_s`` at
              ``kick_t_s``) stands for the operator flicking the sheet. Stepped exactly
              (ZOH on the push) with the current gap.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any

from ladrc_contract.ops import SCALAR
from ladrc_contract.schema import param
import numpy as np
from scipy import linalg, signal

from .axis import H_S, ParamError, check_fields

INF = math.inf


def _window(t: np.ndarray, t_start: float, t_end: float) -> np.ndarray:
    return (t >= t_start) & (t < t_end)


@dataclass(frozen=True)
class Flat:
    """Constant sheet height."""

    height_mm: float = param(0.0)

    def __post_init__(self) -> None:
        check_fields(self)

    def evaluate(self, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Height over ``t_s``."""
        return np.full_like(t_s, self.height_mm)


@dataclass(frozen=True)
class Step:
    """A step of ``size_mm`` at ``t_s``."""

    t_s: float = param(0.0, ge=0.0)
    size_mm: float = param(1.0)

    def __post_init__(self) -> None:
        check_fields(self)

    def evaluate(self, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Height over ``t_s``."""
        return np.where(t_s >= self.t_s, self.size_mm, 0.0)


@dataclass(frozen=True)
class Sine:
    """A sine of amplitude ``amp_mm`` and frequency ``freq_hz`` inside a time window."""

    amp_mm: float = param(0.5, ge=0.0)
    freq_hz: float = param(1.0, gt=0.0)
    phase_deg: float = param(0.0)
    t_start_s: float = param(0.0, ge=0.0)
    t_end_s: float = param(INF, gt=0.0, inf_ok=True)

    def __post_init__(self) -> None:
        check_fields(self)
        if self.t_end_s <= self.t_start_s:
            raise ParamError('t_end_s', f'{self.t_end_s} must be after t_start_s')

    def evaluate(self, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Height over ``t_s``."""
        tau = t_s - self.t_start_s
        z = self.amp_mm * np.sin(2 * np.pi * self.freq_hz * tau + np.radians(self.phase_deg))
        return np.where(_window(t_s, self.t_start_s, self.t_end_s), z, 0.0)


@dataclass(frozen=True)
class Chirp:
    """A linear frequency sweep ``f0_hz -> f1_hz`` over ``sweep_s`` (notes §5.2: 0-5 Hz)."""

    amp_mm: float = param(0.5, ge=0.0)
    f0_hz: float = param(0.0, ge=0.0)
    f1_hz: float = param(5.0, gt=0.0)
    sweep_s: float = param(10.0, gt=0.0)
    t_start_s: float = param(0.0, ge=0.0)

    def __post_init__(self) -> None:
        check_fields(self)

    def evaluate(self, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Height over ``t_s``."""
        tau = t_s - self.t_start_s
        # phi=-90 turns scipy's cosine into a sine, so the sweep starts from 0 mm.
        z = self.amp_mm * signal.chirp(tau, self.f0_hz, self.sweep_s, self.f1_hz,
                                       method='linear', phi=-90)
        return np.where(_window(t_s, self.t_start_s, self.t_start_s + self.sweep_s), z, 0.0)


@dataclass(frozen=True)
class Square:
    """A ``+-amp_mm`` square wave inside a time window."""

    amp_mm: float = param(0.5, ge=0.0)
    freq_hz: float = param(1.0, gt=0.0)
    t_start_s: float = param(0.0, ge=0.0)
    t_end_s: float = param(INF, gt=0.0, inf_ok=True)

    def __post_init__(self) -> None:
        check_fields(self)

    def evaluate(self, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Height over ``t_s``."""
        z = self.amp_mm * signal.square(2 * np.pi * self.freq_hz * (t_s - self.t_start_s))
        return np.where(_window(t_s, self.t_start_s, self.t_end_s), z, 0.0)


@dataclass(frozen=True)
class Triangle:
    """A ``+-amp_mm`` triangle wave inside a time window."""

    amp_mm: float = param(0.5, ge=0.0)
    freq_hz: float = param(1.0, gt=0.0)
    t_start_s: float = param(0.0, ge=0.0)
    t_end_s: float = param(INF, gt=0.0, inf_ok=True)

    def __post_init__(self) -> None:
        check_fields(self)

    def evaluate(self, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Height over ``t_s``."""
        phase = 2 * np.pi * self.freq_hz * (t_s - self.t_start_s)
        z = self.amp_mm * signal.sawtooth(phase, width=0.5)
        return np.where(_window(t_s, self.t_start_s, self.t_end_s), z, 0.0)


@dataclass(frozen=True)
class Waviness:
    """Band-limited random waviness of ``rms_mm`` below ``cutoff_hz`` (temporal)."""

    rms_mm: float = param(0.05, ge=0.0)
    cutoff_hz: float = param(2.0, '', 'must be below the Nyquist rate 1 kHz', gt=0.0, lt=1000.0)

    def __post_init__(self) -> None:
        check_fields(self)

    def evaluate(self, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Height over ``t_s`` (uniformly sampled), drawn from ``rng``."""
        n = t_s.size
        if n < 30 or self.rms_mm == 0.0:
            rng.standard_normal(n)  # same draws as below: the rest of the run stays the same
            return np.zeros(n)
        fs = 1.0 / (t_s[1] - t_s[0])
        # Filter a longer record and keep its middle: a low cutoff has a time constant of
        # ~fs/cutoff samples, far beyond sosfiltfilt's edge padding, and the edges would carry
        # a start-up transient many times the requested RMS (a 2 mm sheet jump at t = 0).
        pad = int(3.0 * fs / self.cutoff_hz)
        white = rng.standard_normal(n + 2 * pad)
        sos = signal.butter(4, self.cutoff_hz, btype='low', fs=fs, output='sos')
        z = signal.sosfiltfilt(sos, white)[pad:pad + n]
        z -= z.mean()
        rms = math.sqrt(float(np.mean(z * z)))
        return z * (self.rms_mm / rms) if rms > 0.0 else z


@dataclass(frozen=True)
class Ridge:
    """Tube-ridge crossing: a raised-cosine bump with a feedback-gain drop over it."""

    t_s: float = param(1.0, '', 'time of the (first) crest', ge=0.0)
    height_mm: float = param(0.3)
    width_s: float = param(0.05, gt=0.0)
    gain_drop: float = param(0.3, '', 'fraction of feedback gain lost at crest', ge=0.0, lt=1.0)
    period_s: float = param(0.0, '', '0 = a single ridge', ge=0.0)
    count: int = param(1, ge=1)

    def __post_init__(self) -> None:
        check_fields(self)

    def _shape(self, t_s: np.ndarray) -> np.ndarray:
        out = np.zeros_like(t_s)
        n = self.count if self.period_s > 0.0 else 1
        for k in range(n):
            d = t_s - (self.t_s + k * self.period_s)
            inside = np.abs(d) < 0.5 * self.width_s
            out += np.where(inside, 0.5 * (1.0 + np.cos(2 * np.pi * d / self.width_s)), 0.0)
        return out

    def evaluate(self, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Height over ``t_s``."""
        return self.height_mm * self._shape(t_s)

    def gain(self, t_s: np.ndarray) -> np.ndarray:
        """Multiplier on the sensor's feedback gain over ``t_s`` (1 away from the ridge)."""
        return 1.0 - self.gain_drop * np.minimum(self._shape(t_s), 1.0)


@dataclass(frozen=True)
class PlateParams:
    """Thin sheet lifted by the assist gas (notes §5.3 item 5)."""

    natural_freq_hz: float = param(6.0, gt=0.0, lt=1000.0)
    damping_ratio: float = param(0.03, '', 'lightly damped: 0 <= zeta < 1', ge=0.0, lt=1.0)
    gas_k_mm2_s2: float = param(2000.0, '', 'gas push a = k / (gap + g0), mm/s^2', ge=0.0)
    gas_g0_mm: float = param(0.5, '', 'keeps the push finite at contact', gt=0.0)
    gas_on_s: float = param(0.0, ge=0.0)
    kick_t_s: float | None = param(None, ge=0.0)
    kick_velocity_mm_s: float = param(0.0)

    def __post_init__(self) -> None:
        check_fields(self)


def gas_push_mm_s2(ops: Any, gap_mm: Any, gas_k_mm2_s2: float, gas_g0_mm: float) -> Any:
    """Return the gas's push as the plate's acceleration (down: negative), scalar or rows.

    It falls with the gap, clamped at contact: ``-k / (max(gap, 0) + g0)``.
    """
    return -gas_k_mm2_s2 / (ops.where(gap_mm > 0.0, gap_mm, 0.0) + gas_g0_mm)


def plate_step(c: tuple[float, float, float, float, float, float], y_mm: Any, v_mm_s: Any,
               push_mm_s2: Any) -> tuple[Any, Any]:
    """One tick of the plate, exact ZOH with the push held (``c``: Plate.coefficients())."""
    p00, p01, p10, p11, g0, g1 = c
    return (p00 * y_mm + p01 * v_mm_s + g0 * push_mm_s2,
            p10 * y_mm + p11 * v_mm_s + g1 * push_mm_s2)


class Plate:
    """Mass-spring-damper sheet pushed by the gas; ``step(gap_mm)`` advances one tick."""

    def __init__(self, params: PlateParams, h_s: float = H_S):
        self.params = params
        self.h_s = float(h_s)
        w = 2 * math.pi * params.natural_freq_hz
        zeta = params.damping_ratio
        a_c = np.array([[0.0, 1.0], [-w * w, -2 * zeta * w]])
        # exact ZOH: expm of the augmented [[A, B], [0, 0]] gives Phi and Gamma together.
        aug = np.zeros((3, 3))
        aug[:2, :2] = a_c
        aug[1, 2] = 1.0
        e = linalg.expm(aug * self.h_s)
        (self._p00, self._p01), (self._p10, self._p11) = e[:2, :2].tolist()
        self._g0, self._g1 = e[:2, 2].tolist()
        self.y_mm = 0.0
        self.v_mm_s = 0.0
        self.k = 0  # ticks stepped; time is k h (a counter, so runs are bit-reproducible)
        # first tick at or after gas_on_s / kick_t_s (the runner inlines the same rule).
        self.i_gas = _first_tick(params.gas_on_s, self.h_s)
        self.i_kick = -1 if params.kick_t_s is None else _first_tick(params.kick_t_s, self.h_s)
        self.gas_on = self.i_gas == 0
        self.gas_auto = True  # until set_gas() is called, the gas comes on at tick i_gas
        self.gas_k = params.gas_k_mm2_s2
        self.gas_g0 = params.gas_g0_mm

    def push_mm_s2(self, gap_mm: float) -> float:
        """Gas push (downward acceleration, mm/s^2) at ``gap_mm``; falls with the gap."""
        p = self.params
        return p.gas_k_mm2_s2 / ((gap_mm if gap_mm > 0.0 else 0.0) + p.gas_g0_mm)

    def set_gas(self, on: bool) -> None:
        """Switch the assist gas on or off from now on."""
        self.gas_on = bool(on)
        self.gas_auto = False

    def kick(self, velocity_mm_s: float) -> None:
        """Add a velocity to the plate (someone flicks the sheet)."""
        self.v_mm_s += velocity_mm_s

    def coefficients(self) -> tuple[float, float, float, float, float, float]:
        """Exact ZOH update ``(p00, p01, p10, p11, g0, g1)`` of ``(y, v)`` with push ``a``."""
        return self._p00, self._p01, self._p10, self._p11, self._g0, self._g1

    def step(self, gap_mm: float) -> float:
        """Advance one tick with the push held at ``gap_mm``; return the plate height (mm)."""
        k = self.k
        if self.gas_auto and not self.gas_on and k >= self.i_gas:
            self.gas_on = True
        if k == self.i_kick:
            self.v_mm_s += self.params.kick_velocity_mm_s
        # push held over the tick (ZOH), gap clamped at contact (see push_mm_s2).
        a = gas_push_mm_s2(SCALAR, gap_mm, self.gas_k, self.gas_g0) if self.gas_on else 0.0
        self.y_mm, self.v_mm_s = plate_step(self.coefficients(), self.y_mm, self.v_mm_s, a)
        self.k = k + 1
        return self.y_mm


def _first_tick(t_s: float, h_s: float) -> int:
    """Index of the first tick ``k`` with ``k h >= t_s`` (times are ``k * h`` everywhere)."""
    k = max(0, int(math.floor(t_s / h_s)))
    while k * h_s < t_s:
        k += 1
    while k > 0 and (k - 1) * h_s >= t_s:
        k -= 1
    return k


PROFILE_KINDS: dict[str, type] = {
    'flat': Flat, 'step': Step, 'sine': Sine, 'chirp': Chirp, 'square': Square,
    'triangle': Triangle, 'waviness': Waviness, 'ridge': Ridge, 'plate': PlateParams,
}


@dataclass(frozen=True)
class SheetParams:
    """The sheet: a tuple of profiles (at most one ``plate``), summed."""

    profiles: tuple = ()

    def __post_init__(self) -> None:
        plates = [p for p in self.profiles if isinstance(p, PlateParams)]
        if len(plates) > 1:
            raise ParamError('profiles', 'at most one plate profile is allowed')


class Sheet:
    """Sheet surface over a run of ``n_ticks`` ticks: precomputed part plus the plate."""

    def __init__(self, params: SheetParams, n_ticks: int, h_s: float = H_S,
                 rng: np.random.Generator | None = None):
        rng = np.random.default_rng(0) if rng is None else rng
        self.params = params
        self.t_s = np.arange(n_ticks) * h_s
        self.base_mm = np.zeros(n_ticks)
        self.feedback_gain = np.ones(n_ticks)
        self.plate: Plate | None = None
        for prof in params.profiles:
            if isinstance(prof, PlateParams):
                self.plate = Plate(prof, h_s)
                continue
            self.base_mm += prof.evaluate(self.t_s, rng)
            if isinstance(prof, Ridge):
                self.feedback_gain *= prof.gain(self.t_s)

    def height_mm(self, i: int) -> float:
        """Sheet height at tick ``i`` (precomputed part plus the plate's current height)."""
        z = float(self.base_mm[i])
        return z + self.plate.y_mm if self.plate is not None else z
