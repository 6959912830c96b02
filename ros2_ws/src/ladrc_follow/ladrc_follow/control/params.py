"""The controller's parameter set: dataclasses, YAML load/dump, whole-set validation.

One frozen dataclass per section (TD A/B, ESO, Kalman, law, limits, PID
baseline, interpolation) inside :class:`ControllerParams`. Values are SI-like
floats in mm, mm/s, mm/s², s (docs/control-law.md maps every seed integer).

YAML: plain nested sections, or the ROS 2 parameter-file layout
``<node>: {ros__parameters: {...}}`` with nested or dotted keys, so the node
loads the same file with ``--params-file``. ROS parameters cannot be null, so
optional features are switched by a mode string or a bool and "0 = off"
(documented per field), never by ``None``.

Validation looks at the whole set (:func:`validate`) and reports every reason
at once; :func:`check` raises :class:`ParameterError` carrying them all.
Unknown keys are errors naming the key. The ``follow`` section is
:class:`~.follow_params.FollowParams` (the follow state machine's), validated with the rest
of the set; other modules can add whole-set checks to :data:`EXTRA_VALIDATORS`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, is_dataclass, replace
from pathlib import Path
import typing
from typing import Any, Callable

import yaml

from .eso import bandwidth_gains, euler_is_stable, zoh_gains
from .follow_params import FollowParams, follow_problems
from .interp import InterpParams
from .kalman import KalmanParams
from .pid import PIDParams
from .td import TDA_FIRMWARE, TDB_FIRMWARE, TDParams

__all__ = [
    'ControllerParams', 'ESOParams', 'KalmanConfig', 'LawParams', 'LimitParams', 'PIDParams',
    'InterpParams', 'TDParams', 'ParameterError', 'EXTRA_VALIDATORS', 'load_params',
    'params_from_dict', 'params_to_dict', 'dump_params', 'validate', 'check', 'eso_gains',
    'law_gains', 'DEFAULT_NODE_NAME', 'FollowParams',
]

DEFAULT_NODE_NAME = 'ladrc_follow'


@dataclass(frozen=True)
class ESOParams:
    """Extended state observer (notes §3).

    ``order``: plant model order (1: z = (gap, disturbance mm/s), the seed's
    ``CONTROLLER_ORDER 1``; 2: z = (gap, gap rate, disturbance mm/s²)).
    ``gains``: 'explicit' uses ``betas`` (order + 1 values, continuous-time
    β's as in the seed); 'bandwidth' derives them from ``w0_rad_s``. The 'zoh'
    discretization always derives its gains from ``w0_rad_s`` and ``h_s``.
    ``b0``: input gain (order 1: mm/s per mm/s command, 1 in SI for the seed's
    integer 100; order 2: plant gain / T1 in 1/s). Peaking limits (notes §3.4):
    ``disturbance_limit`` clamps |z_{n+1}|, ``disturbance_rate_limit`` clamps its
    change per tick; 0 = off.
    """

    order: int = 1
    discretization: str = 'euler'
    gains: str = 'explicit'
    w0_rad_s: float = 60.0
    betas: tuple[float, ...] = (180.0, 10800.0)
    b0: float = 1.0
    compensator: bool = False
    disturbance_limit: float = 0.0
    disturbance_rate_limit: float = 0.0


@dataclass(frozen=True)
class KalmanConfig:
    """Height Kalman filter (notes §4): fuses the gap reading with encoder increments.

    Off by default, as in the seed's ``UpdateLADRC`` (the filter was tried for
    tube-ridge chatter, not wired into the LADRC path).
    """

    enabled: bool = False
    q_mm2: float = 1e-6
    r_mm2: float = 1e-4
    p0_mm2: float = 1e-4

    def kalman_params(self) -> KalmanParams:
        """Return the estimator's own parameter object."""
        return KalmanParams(q_mm2=self.q_mm2, r_mm2=self.r_mm2, p0_mm2=self.p0_mm2)


@dataclass(frozen=True)
class LawParams:
    """Control law (notes §3.1 forms 1–3; see :mod:`law`).

    ``gains``: 'explicit' uses ``kp``/``kd``; 'bandwidth' derives them from
    ``wc_rad_s`` (order 1: kp = ωc; order 2: kp = ωc², kd = 2ωc). Units: order 1
    kp in 1/s (kd unused); order 2 kp in 1/s², kd in 1/s. Seed: KP = 100 with
    ``/10`` → kp = 10 /s.
    """

    form: int = 3
    gains: str = 'explicit'
    kp: float = 10.0
    kd: float = 0.0
    wc_rad_s: float = 10.0


@dataclass(frozen=True)
class LimitParams:
    """Output limits of the LADRC: saturation and per-tick change a_max·h (``UpdateLADRC``)."""

    v_max_mm_s: float = 150.0
    a_max_mm_s2: float = 4000.0


# TD defaults: ``CompELDTInit`` ints TDA (22, 13, 30, 15), TDB (12, 40, 100, 0) after td.py's
# mapping (k1, k2 = int/10, R in 1/s, α = Fc in 1/s as in the notes' MATLAB sets).
def _tda() -> TDParams:
    return TDA_FIRMWARE


def _tdb() -> TDParams:
    return TDB_FIRMWARE


@dataclass(frozen=True)
class ControllerParams:
    """The whole parameter set of the follow controller."""

    h_s: float = 0.0005
    td_a: TDParams = field(default_factory=_tda)
    td_b: TDParams = field(default_factory=_tdb)
    eso: ESOParams = field(default_factory=ESOParams)
    kalman: KalmanConfig = field(default_factory=KalmanConfig)
    law: LawParams = field(default_factory=LawParams)
    limits: LimitParams = field(default_factory=LimitParams)
    pid: PIDParams = field(default_factory=PIDParams)
    interp: InterpParams = field(default_factory=InterpParams)
    follow: FollowParams = field(default_factory=FollowParams)

    def replace(self, **changes: Any) -> ControllerParams:
        """Return a copy with sections or values replaced (dataclasses.replace)."""
        return replace(self, **changes)


class ParameterError(ValueError):
    """Invalid parameter set; ``reasons`` lists every problem found."""

    def __init__(self, reasons: list[str]) -> None:
        self.reasons = list(reasons)
        super().__init__('invalid controller parameters:\n  - ' + '\n  - '.join(self.reasons))


# Checks added by other modules (the follow state machine): f(params) -> reasons.
EXTRA_VALIDATORS: list[Callable[[ControllerParams], list[str]]] = []


# ---------------------------------------------------------------------------
# derived values

def eso_gains(p: ControllerParams) -> tuple[float, ...]:
    """Observer gains the controller uses: β's ('euler') or the ZOH gains ('zoh')."""
    e = p.eso
    if e.discretization == 'zoh':
        return tuple(float(b) for b in zoh_gains(e.order, e.w0_rad_s, p.h_s))
    if e.gains == 'bandwidth':
        return tuple(float(b) for b in bandwidth_gains(e.order, e.w0_rad_s))
    return tuple(float(b) for b in e.betas)


def law_gains(p: ControllerParams) -> tuple[float, float]:
    """``(kp, kd)`` of the law, explicit or from the bandwidth ωc."""
    from .law import gains_from_bandwidth
    if p.law.gains == 'bandwidth':
        return gains_from_bandwidth(p.eso.order, p.law.wc_rad_s)
    return float(p.law.kp), float(p.law.kd)


# ---------------------------------------------------------------------------
# dict / YAML conversion

def _hints(cls) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _convert(value: Any, tp: Any, key: str, errors: list[str]) -> Any:
    origin = typing.get_origin(tp)
    if is_dataclass(tp):
        if not isinstance(value, dict):
            errors.append(f'{key} must be a section (mapping), got {value!r}')
            return None
        return _build(tp, value, key, errors)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            errors.append(f'{key} must be a number, got {value!r}')
            return None
        return float(value)
    if tp is int:
        if isinstance(value, float) and value.is_integer():
            return int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            errors.append(f'{key} must be an integer, got {value!r}')
            return None
        return value
    if tp is bool:
        if not isinstance(value, bool):
            errors.append(f'{key} must be true or false, got {value!r}')
            return None
        return value
    if tp is str:
        if not isinstance(value, str):
            errors.append(f'{key} must be a string, got {value!r}')
            return None
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)) or any(
                isinstance(v, bool) or not isinstance(v, (int, float)) for v in value):
            errors.append(f'{key} must be a list of numbers, got {value!r}')
            return None
        return tuple(float(v) for v in value)
    if tp is dict or origin is dict:
        if not isinstance(value, dict):
            errors.append(f'{key} must be a mapping, got {value!r}')
            return None
        return dict(value)
    return value


def _build(cls, d: dict, prefix: str, errors: list[str]):
    hints = _hints(cls)
    names = [f.name for f in fields(cls)]
    kwargs = {}
    for k, v in d.items():
        key = f'{prefix}.{k}' if prefix else str(k)
        if k not in hints:
            errors.append(f"unknown key '{key}' (known in {prefix or 'the top level'}: "
                          f"{', '.join(names)})")
            continue
        conv = _convert(v, hints[k], key, errors)
        if conv is not None:
            kwargs[k] = conv
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:  # a section's own constructor refused
        errors.append(f'{prefix or "parameters"}: {exc}')
        return None


def _nest_dotted(d: dict) -> dict:
    """Turn ROS-style dotted keys ('eso.b0') into nested mappings; nested keys pass."""
    out: dict = {}
    for k, v in d.items():
        if isinstance(v, dict):
            v = _nest_dotted(v)
        parts = str(k).split('.')
        node = out
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ParameterError([f"key '{k}' conflicts with a value at '{part}'"])
        last = parts[-1]
        if isinstance(v, dict) and isinstance(node.get(last), dict):
            node[last].update(v)
        else:
            node[last] = v
    return out


def _unwrap_ros(d: dict, node_name: str | None) -> dict:
    """Return the parameters of a ROS 2 params file, or ``d`` if it is plain."""
    ros = {k: v for k, v in d.items()
           if isinstance(v, dict) and 'ros__parameters' in v}
    if not ros:
        return d
    if len(ros) != len(d):
        extra = sorted(set(d) - set(ros))
        raise ParameterError([f'ROS parameter file mixes node sections with plain keys {extra}'])
    if node_name is not None:
        for k in (node_name, '/' + node_name.lstrip('/'), '/**'):
            if k in ros:
                return ros[k]['ros__parameters'] or {}
        raise ParameterError([f"no section for node '{node_name}' in the ROS parameter file "
                              f'(has {sorted(ros)})'])
    if len(ros) > 1:
        raise ParameterError([f'ROS parameter file has several node sections {sorted(ros)}; '
                              'name the node'])
    return next(iter(ros.values()))['ros__parameters'] or {}


def params_from_dict(d: dict | None, node_name: str | None = None,
                     validate_set: bool = True) -> ControllerParams:
    """Build :class:`ControllerParams` from a (partial) nested, dotted or ROS-layout dict.

    Missing values keep their defaults. Raises :class:`ParameterError` listing
    unknown keys, wrong types and (with ``validate_set``) every validation reason.
    """
    if d is None:
        d = {}
    if not isinstance(d, dict):
        raise ParameterError([f'parameters must be a mapping, got {type(d).__name__}'])
    d = _nest_dotted(_unwrap_ros(d, node_name))
    errors: list[str] = []
    p = _build(ControllerParams, d, '', errors)
    if errors:
        raise ParameterError(errors)
    if validate_set:
        check(p)
    return p


def params_to_dict(p: ControllerParams) -> dict:
    """Nested dict of plain YAML types (tuples become lists); inverse of params_from_dict."""
    def conv(obj):
        if is_dataclass(obj):
            return {f.name: conv(getattr(obj, f.name)) for f in fields(obj)}
        if isinstance(obj, tuple):
            return [conv(v) for v in obj]
        if isinstance(obj, dict):
            return {k: conv(v) for k, v in obj.items()}
        return obj
    return conv(p)


def dump_params(p: ControllerParams, ros_node: str | None = DEFAULT_NODE_NAME) -> str:
    """YAML text of ``p``; in the ROS 2 layout under ``ros_node`` unless it is None."""
    d = params_to_dict(p)
    if ros_node is not None:
        d = {ros_node: {'ros__parameters': d}}
    return yaml.safe_dump(d, sort_keys=False, default_flow_style=False)


def load_params(path: str | Path, node_name: str | None = None) -> ControllerParams:
    """Load and validate a parameter file (plain or ROS 2 layout)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ParameterError([f'cannot read parameter file {path}: {exc}']) from exc
    try:
        d = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ParameterError([f'{path} is not valid YAML: {exc}']) from exc
    return params_from_dict(d, node_name=node_name)


# ---------------------------------------------------------------------------
# validation

def _td_problems(name: str, td: TDParams, h_s: float) -> list[str]:
    # TDParams.problems(h_s) also checks the discrete (firmware-order) step's stability
    return [f'{name}: {m}' for m in td.problems(h_s if h_s > 0.0 else None)]


def _euler_bound(order: int, betas: tuple[float, ...], w0: float | None, h_s: float) -> str:
    """Largest stable ω0·h for bandwidth gains of this order (bisection on euler_is_stable)."""
    lo, hi = 0.0, 4.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if euler_is_stable(order, bandwidth_gains(order, mid / h_s), h_s):
            lo = mid
        else:
            hi = mid
    return f'{lo:.3f}'


def _eso_problems(p: ControllerParams) -> list[str]:
    e = p.eso
    out = []
    if e.order not in (1, 2):
        out.append(f'eso.order must be 1 or 2 (plant model order), got {e.order!r}')
    if e.discretization not in ('euler', 'zoh'):
        out.append(f"eso.discretization must be 'euler' or 'zoh', got {e.discretization!r}")
    if e.gains not in ('explicit', 'bandwidth'):
        out.append(f"eso.gains must be 'explicit' or 'bandwidth', got {e.gains!r}")
    if e.b0 == 0.0:
        out.append('eso.b0 = 0: the control law divides by b0')
    elif not e.b0 > 0.0:
        out.append(f'eso.b0 = {e.b0}: must be > 0 (a positive command raises the nozzle '
                   'and widens the gap)')
    uses_w0 = e.gains == 'bandwidth' or e.discretization == 'zoh'
    if uses_w0 and not e.w0_rad_s > 0.0:
        out.append(f'eso.w0_rad_s must be > 0, got {e.w0_rad_s!r}')
    if e.discretization == 'zoh' and e.gains == 'explicit':
        out.append("eso: the 'zoh' discretization derives its gains from w0_rad_s and h_s; "
                   "set eso.gains: 'bandwidth'")
    explicit = e.gains == 'explicit' and e.discretization == 'euler'
    if explicit and e.order in (1, 2):
        if len(e.betas) != e.order + 1:
            out.append(f'eso.betas needs {e.order + 1} values for order {e.order}, '
                       f'got {len(e.betas)}')
        elif not all(b > 0.0 for b in e.betas):
            out.append(f'eso.betas must all be > 0, got {list(e.betas)}')
    for name in ('disturbance_limit', 'disturbance_rate_limit'):
        v = getattr(e, name)
        if not v >= 0.0:
            out.append(f'eso.{name} must be >= 0 (0 = off), got {v!r}')
    if out or not p.h_s > 0.0:
        return out
    if e.discretization == 'euler':
        betas = eso_gains(p)
        if not euler_is_stable(e.order, betas, p.h_s):
            bound = _euler_bound(e.order, betas, None, p.h_s)
            if e.gains == 'bandwidth':
                out.append(f'eso: explicit-Euler observer with ω0·h = {e.w0_rad_s * p.h_s:.3g} '
                           f'is unstable (bound {bound} for order {e.order})')
            else:
                out.append(f'eso: explicit-Euler observer with betas {list(betas)} at h = '
                           f'{p.h_s} s is unstable (bandwidth gains are stable up to '
                           f'ω0·h = {bound} for order {e.order})')
    return out


def _law_problems(p: ControllerParams) -> list[str]:
    law = p.law
    out = []
    if law.form not in (1, 2, 3):
        out.append(f'law.form must be 1, 2 or 3 (notes §3.1), got {law.form!r}')
    if law.gains not in ('explicit', 'bandwidth'):
        out.append(f"law.gains must be 'explicit' or 'bandwidth', got {law.gains!r}")
        return out
    if law.gains == 'bandwidth':
        if not law.wc_rad_s > 0.0:
            out.append(f'law.wc_rad_s must be > 0, got {law.wc_rad_s!r}')
            return out
    else:
        if not law.kp > 0.0:
            out.append(f'law.kp must be > 0, got {law.kp!r}')
        if p.eso.order == 2 and not law.kd > 0.0:
            out.append(f'law.kd must be > 0 for the order-2 law, got {law.kd!r}')
        if out:
            return out
    if p.eso.order in (1, 2) and p.h_s > 0.0:
        kp, kd = law_gains(p)
        # nominal loop with a perfect ESO: order 1 e(k+1) = (1 − kp·h)e
        if p.eso.order == 1 and not kp * p.h_s < 1.0:
            out.append(f'law: kp·h = {kp * p.h_s:.3g} >= 1, the sampled loop would '
                       'overshoot every tick; lower law.kp')
    return out


def _limit_problems(p: ControllerParams) -> list[str]:
    lim = p.limits
    out = []
    if not lim.v_max_mm_s > 0.0:
        out.append(f'limits.v_max_mm_s must be > 0, got {lim.v_max_mm_s!r}')
    if not lim.a_max_mm_s2 > 0.0:
        out.append(f'limits.a_max_mm_s2 must be > 0, got {lim.a_max_mm_s2!r}')
    if out:
        return out
    for sec, obj in (('pid', p.pid), ('interp', p.interp)):
        if obj.v_max_mm_s > lim.v_max_mm_s:
            out.append(f'limits.v_max_mm_s ({lim.v_max_mm_s:g}) below {sec}.v_max_mm_s '
                       f'({obj.v_max_mm_s:g}): {sec} would command speeds the axis limit '
                       'forbids (contradiction)')
        if obj.a_max_mm_s2 > lim.a_max_mm_s2:
            out.append(f'limits.a_max_mm_s2 ({lim.a_max_mm_s2:g}) below {sec}.a_max_mm_s2 '
                       f'({obj.a_max_mm_s2:g}): {sec} would accelerate harder than the axis '
                       'limit allows (contradiction)')
    return out


def validate(p: ControllerParams) -> list[str]:
    """Return every reason why ``p`` cannot run (empty list: valid)."""
    out: list[str] = []
    if not p.h_s > 0.0:
        out.append(f'h_s must be > 0, got {p.h_s!r}')
    elif p.h_s > 0.01:
        out.append(f'h_s = {p.h_s} s: the controller is designed for a 2 kHz tick '
                   '(0.0005 s); a period over 10 ms is certainly a unit mistake')
    out += _td_problems('td_a', p.td_a, p.h_s)
    out += _td_problems('td_b', p.td_b, p.h_s)
    out += _eso_problems(p)
    out += [f'kalman: {m}' for m in p.kalman.kalman_params().problems()]
    out += _law_problems(p)
    out += _limit_problems(p)
    out += p.pid.problems()
    out += p.interp.problems()
    if isinstance(p.follow, FollowParams):
        out += p.follow.problems()
        if not p.follow.problems():
            out += follow_problems(p)
    else:
        out.append(f'follow must be a FollowParams section, got {type(p.follow).__name__}')
    for extra in EXTRA_VALIDATORS:
        out += extra(p)
    return out


def check(p: ControllerParams) -> ControllerParams:
    """Raise :class:`ParameterError` with every reason if ``p`` is invalid; return ``p``."""
    reasons = validate(p)
    if reasons:
        raise ParameterError(reasons)
    return p
