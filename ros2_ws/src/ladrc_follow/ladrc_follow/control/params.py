"""The controller's parameter set: dataclasses, YAML load/dump, whole-set validation.

One frozen dataclass per section (TD A/B, ESO, Kalman, law, limits, PID
baseline, interpolation, follow state machine) inside :class:`ControllerParams`. Each
parameter is declared once, with :func:`.schema.param` (type, default, unit, range,
description, seed section, run-time changeable); the sections of the estimators and
baselines are declared in their own modules. Values are SI-like floats in mm, mm/s, mm/s², s
(docs/control-law.md maps every seed integer; docs/parameters.md is the generated table).

YAML: plain nested sections, or the ROS 2 parameter-file layout
``<node>: {ros__parameters: {...}}`` with nested or dotted keys, so the node
loads the same file with ``--params-file``. ROS parameters cannot be null, so
optional features are switched by a mode string or a bool and "0 = off"
(documented per field), never by ``None``.

Reading a mapping is the contract's one loader (``ladrc_contract.schema.load``: types,
unknown keys naming the key, nested sections). Validation looks at the whole set
(:func:`validate`) and reports every reason at once; :func:`check` raises
:class:`ParameterError` carrying them all. Per-value checks come from the declarations;
the checks that relate several parameters (:data:`CROSS_CHECKS`: discrete stability of the
TDs and the observer, contradicting limits, the follow windows) are here, next to the set;
other modules can add whole-set checks to :data:`EXTRA_VALIDATORS`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from typing import Any, Callable

from ladrc_contract.schema import (
    NOT_MAPPING,
    UNKNOWN_KEY,
    WRONG_TYPE,
    LoadError,
    Problem,
    entries,
    field_problems,
    load,
    param,
)
import numpy as np
import yaml

from .cap_table import CapTableParams
from .cnc_params import CncParams, cnc_problems
from .edge import EdgeParams
from .eso import bandwidth_gains, euler_is_stable, fal_alphas, zoh_gains
from .follow_params import FollowParams
from .interp import InterpParams
from .kalman import KalmanParams
from .pid import PIDParams
from .stability import StabilityParams
from .td import TDA_FIRMWARE, TDB_FIRMWARE, TDParams

__all__ = [
    'ControllerParams', 'EdgeParams', 'ESOParams', 'KalmanParams', 'LawParams', 'LimitParams',
    'PIDParams',
    'InterpParams', 'TDParams', 'ParameterError', 'EXTRA_VALIDATORS', 'load_params',
    'params_from_dict', 'params_to_dict', 'dump_params', 'validate', 'check', 'eso_gains',
    'law_gains', 'DEFAULT_NODE_NAME', 'FollowParams', 'parameter_file', 'CROSS_CHECKS',
]

DEFAULT_NODE_NAME = 'ladrc_follow'


@dataclass(frozen=True)
class ESOParams:
    """Extended state observer (notes §3).

    ``order`` 1: z = (gap, disturbance mm/s), the seed's ``CONTROLLER_ORDER 1``; 2: z = (gap,
    gap rate, disturbance mm/s²). ``gains`` 'explicit' uses ``betas`` (order + 1 continuous-time
    β's as in the seed), 'bandwidth' derives them from ``w0_rad_s``; the 'zoh' discretization
    always derives its gains from ``w0_rad_s`` and ``h_s``. ``b0``: order 1 mm/s per mm/s of
    command (1 in SI for the seed's integer 100); order 2 plant gain / T1 in 1/s.
    """

    order: int = param(1, '', 'plant model order of the observer (1: gap, disturbance; '
                       '2: gap, gap rate, disturbance)', choices=(1, 2),
                       seed='notes §3 CONTROLLER_ORDER')
    discretization: str = param('euler', '', "'euler': the firmware's EsoUpdate; 'zoh': "
                                'current estimator with poles at exp(−ω0·h)',
                                choices=('euler', 'zoh'), seed='notes §3.3')
    gains: str = param('explicit', '', "'explicit': eso.betas; 'bandwidth': from eso.w0_rad_s",
                       choices=('explicit', 'bandwidth'), seed='notes §3.3 GetLADRCParam')
    w0_rad_s: float = param(60.0, 'rad/s', 'observer bandwidth ω0 (bandwidth gains, zoh)',
                            gt=0.0, le=20000.0, seed='notes §3.3')
    betas: tuple[float, ...] = param((180.0, 10800.0), '1/s^i', 'explicit observer gains '
                                     'β1..β(order+1) (seed (3ω, 3ω²) at ω = 60)',
                                     gt=0.0, le=1e10, seed='notes §3.3')
    b0: float = param(1.0, 'order 1: 1; order 2: 1/s', 'input gain b0 (order 1: axis mm/s per '
                      'mm/s of command; order 2: plant gain / T1)',
                      ge=0.01, le=1e5, seed='notes §1, §3')
    compensator: bool = param(False, '', 'feed-forward compensation of the observation error',
                              seed='paper eq. 22')
    disturbance_limit: float = param(0.0, 'mm/s or mm/s²', 'clamp of |disturbance estimate|; '
                                     '0 = off', ge=0.0, le=1e7, seed='notes §3.4')
    disturbance_rate_limit: float = param(0.0, 'per tick', 'clamp of the disturbance '
                                          "estimate's change per tick; 0 = off",
                                          ge=0.0, le=1e7, seed='notes §3.4')
    nonlinear: str = param('off', '', "fal on the observer's corrections: 'off' (LESO), "
                           "'disturbance' (only the extended state's, notes §5.2 fix 3) or "
                           "'all' (the NESO of paper eq. 4); explicit Euler only",
                           choices=('off', 'disturbance', 'all'), seed='notes §1.2, §5.2')
    fal_alpha: float = param(0.5, '1', "fal exponent α: 'disturbance' uses α on the extended "
                             "state; 'all' uses α^i on state i (paper eq. 38: 0.5, 0.25, …)",
                             gt=0.0, le=1.0, seed='paper eq. 6, 38')
    fal_delta_mm: float = param(0.05, 'mm', 'half-width δ of the linear zone of fal (inside, '
                                'gain β·δ^(α−1))', gt=0.0, le=10.0, seed='paper eq. 6, 38')
    fal_table: bool = param(False, '', 'evaluate fal by table lookup, as the firmware would '
                            '(notes §1.2), instead of directly', seed='notes §1.2, §6')
    fal_table_size: int = param(257, 'entries', 'lookup table entries over 0..range (odd '
                                'symmetry)', ge=3, le=100000, seed='notes §6')
    fal_table_range_mm: float = param(2.0, 'mm', 'table range ±; beyond it the last segment '
                                      'is extended', gt=0.0, le=100.0, seed='notes §6')


@dataclass(frozen=True)
class LawParams:
    """Control law (notes §3.1 forms 1–3; see :mod:`law`).

    ``gains`` 'explicit' uses ``kp``/``kd``; 'bandwidth' derives them from ``wc_rad_s`` (order
    1: kp = ωc; order 2: kp = ωc², kd = 2ωc). Order 1 kp in 1/s (kd unused); order 2 kp in
    1/s², kd in 1/s. Seed: KP = 100 with ``/10`` → kp = 10 /s.
    """

    form: int = param(3, '', 'law form: 1 TD r, ṙ; 2 raw target; 3 TD with feed-forward '
                      '(seed)', choices=(1, 2, 3), seed='notes §3.1')
    gains: str = param('explicit', '', "'explicit': law.kp, law.kd; 'bandwidth': from "
                       'law.wc_rad_s', choices=('explicit', 'bandwidth'), seed='notes §3.1')
    kp: float = param(10.0, '1/s (order 2: 1/s²)', 'proportional gain', gt=0.0, le=1e7,
                      seed='notes §3.1 KP')
    kd: float = param(0.0, '1/s', 'derivative gain (order 2 only)', ge=0.0, le=1e4,
                      seed='notes §3.1 KD')
    wc_rad_s: float = param(10.0, 'rad/s', 'controller bandwidth ωc (bandwidth gains)',
                            gt=0.0, le=2000.0, seed='notes §3.1')


@dataclass(frozen=True)
class LimitParams:
    """Output limits of every command: saturation and per-tick change a_max·h (``UpdateLADRC``)."""

    v_max_mm_s: float = param(150.0, 'mm/s', 'output saturation ±v_max', ge=0.1, le=1000.0,
                              seed='notes §3.4 UpdateLADRC')
    a_max_mm_s2: float = param(4000.0, 'mm/s²', 'acceleration limit: per-tick change a_max·h',
                               ge=10.0, le=1e6, seed='notes §3.4 UpdateLADRC')
    v_down_max_mm_s: float = param(150.0, 'mm/s', 'speed limit toward the sheet (slower going '
                                   'down than up, as TF5200; capped by v_max_mm_s)', ge=0.1,
                                   le=1000.0, seed='Beckhoff TF5200')
    soft_z_min_mm: float = param(-1000.0, 'mm', 'soft travel limit, bottom (encoder position): '
                                 'no command moves the axis below it, in any state',
                                 ge=-10000.0, le=10000.0)
    soft_z_max_mm: float = param(1000.0, 'mm', 'soft travel limit, top (encoder position): no '
                                 'command moves the axis above it, in any state',
                                 ge=-10000.0, le=10000.0)
    soft_z_tau_s: float = param(0.05, 's', 'approach time constant at a soft limit: the speed '
                                'toward it is at most (distance left) / soft_z_tau_s',
                                ge=0.005, le=10.0)


# TD defaults: ``CompELDTInit`` ints TDA (22, 13, 30, 15), TDB (12, 40, 100, 0) after td.py's
# mapping (k1, k2 = int/10, R in 1/s, α = Fc in 1/s as in the notes' MATLAB sets).
def _tda() -> TDParams:
    return TDA_FIRMWARE


def _tdb() -> TDParams:
    return TDB_FIRMWARE


@dataclass(frozen=True)
class ControllerParams:
    """The whole parameter set of the follow controller."""

    h_s: float = param(0.0005, 's', 'controller tick period (2 kHz)', ge=1e-5, le=0.01,
                       runtime=False, seed='notes SAMPLE_PERIOD 2000')
    td_a: TDParams = field(default_factory=_tda)
    td_b: TDParams = field(default_factory=_tdb)
    eso: ESOParams = field(default_factory=ESOParams)
    kalman: KalmanParams = field(default_factory=KalmanParams)
    law: LawParams = field(default_factory=LawParams)
    limits: LimitParams = field(default_factory=LimitParams)
    pid: PIDParams = field(default_factory=PIDParams)
    interp: InterpParams = field(default_factory=InterpParams)
    follow: FollowParams = field(default_factory=FollowParams)
    edge: EdgeParams = field(default_factory=EdgeParams)
    stability: StabilityParams = field(default_factory=StabilityParams)
    sensor: CapTableParams = field(default_factory=CapTableParams)
    cnc: CncParams = field(default_factory=CncParams)

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

def _reason(p: Problem) -> str:
    """One :class:`ParameterError` reason of a loader problem, in the validation's wording."""
    if p.kind == UNKNOWN_KEY:
        section = p.path.rpartition('.')[0] or 'the top level'
        return f"unknown key '{p.path}' (known in {section}: {', '.join(p.allowed)})"
    if p.kind == NOT_MAPPING and p.path:
        return f'{p.path} must be a section (mapping), got {p.value!r}'
    if p.kind == WRONG_TYPE:
        return f'{p.path} = {p.value!r}: must be {p.expected}{p.hint}'
    return str(p)


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


def dotted(d: dict, prefix: str = '') -> dict[str, Any]:
    """Flatten a nested parameter mapping to dotted names ('eso.b0'); the inverse of nesting."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(dotted(v, f'{prefix}{k}.'))
        else:
            out[f'{prefix}{k}'] = v
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

    Missing values keep their defaults. Raises :class:`ParameterError` listing unknown keys,
    wrong types and (with ``validate_set``) every validation reason. It does not gate: a
    caller that loads a set to run it calls the stability gate itself
    (``ladrc_follow.analysis.gate.check_gate``).
    """
    if d is None:
        d = {}
    if not isinstance(d, dict):
        raise ParameterError([f'parameters must be a mapping, got {type(d).__name__}'])
    d = _nest_dotted(_unwrap_ros(d, node_name))
    try:  # the ranges are the validation's (every reason at once, below)
        p = load(ControllerParams, d, base=ControllerParams(), ranges=False)
    except LoadError as exc:
        raise ParameterError([_reason(q) for q in exc.problems]) from None
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


PARAMETER_FILE_HEADER = """\
# Parameters of the LADRC height-follow controller, ROS 2 parameter-file layout.
# GENERATED from the parameter declarations (ladrc_follow/control): `ladrc params --yaml`.
# Every key, its unit, range and meaning: docs/parameters.md (generated from the same place).
# Load: ros2 run ladrc_follow follow_node --ros-args --params-file follow.yaml
#       or ladrc_follow.control.params.load_params(path) (plain nested YAML works too).
# `/**` applies to the follow node under any name or namespace.
"""


def _yaml_value(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, tuple):
        return '[' + ', '.join(_yaml_value(float(v)) for v in value) + ']'
    if isinstance(value, str):
        # quoted when YAML would read it back as something else ('' is null, off is false)
        return value if yaml.safe_load(value) == value else "'" + value.replace("'", "''") + "'"
    text = repr(value)
    if isinstance(value, float) and 'e' in text and '.' not in text:
        text = text.replace('e', '.0e')  # YAML 1.1 (PyYAML) reads 1e-06 as a string
    return text


def parameter_file(p: ControllerParams | None = None) -> str:
    """Return the commented ROS 2 parameter file of ``p`` (defaults), from the declarations."""
    p = p if p is not None else ControllerParams()
    lines = [PARAMETER_FILE_HEADER.rstrip('\n'), '/**:', '  ros__parameters:']
    section = None
    for e in entries(p):
        *head, key = e.name.split('.')
        if head and head[0] != section:
            section = head[0]
            lines.append(f'    {section}:')
        indent = '      ' if head else '    '
        unit = f'[{e.spec.unit}] ' if e.spec.unit else ''
        rng = f'{e.spec.range_text()}: ' if e.spec.range_text() else ''
        lines.append(f'{indent}{key}: {_yaml_value(e.value)}  # {unit}{rng}{e.spec.description}')
    return '\n'.join(lines) + '\n'


def load_params(path: str | Path, node_name: str | None = None) -> ControllerParams:
    """Load and validate a parameter file (plain or ROS 2 layout), without the gate."""
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

def _euler_bound(order: int, h_s: float) -> str:
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
    if e.discretization == 'zoh' and e.gains == 'explicit':
        return ["eso: the 'zoh' discretization derives its gains from w0_rad_s and h_s; "
                "set eso.gains: 'bandwidth'"]
    if e.gains == 'explicit' and len(e.betas) != e.order + 1:
        return [f'eso.betas needs {e.order + 1} values for order {e.order}, got {len(e.betas)}']
    if e.nonlinear != 'off':
        if e.compensator:
            return [f'eso.compensator (paper eq. 22, linear D_i = β_(i−1)·e1) with eso.nonlinear '
                    f'{e.nonlinear!r}: the compensator of a fal-ESO is not implemented']
        if e.discretization != 'euler':
            return [f"eso.nonlinear {e.nonlinear!r} runs on the explicit-Euler observer (the "
                    "firmware's); set eso.discretization: 'euler'"]
        if e.fal_table and e.fal_table_range_mm <= e.fal_delta_mm:
            return [f'eso.fal_table_range_mm ({e.fal_table_range_mm:g}) must exceed '
                    f'eso.fal_delta_mm ({e.fal_delta_mm:g})']
        # inside |e| <= δ the fal-ESO is a LESO with gains β_i·δ^(α_i − 1): its stiffest zone
        lin = [b * e.fal_delta_mm ** (a - 1.0) for b, a in
               zip(eso_gains(p), fal_alphas(e.order, e.nonlinear, e.fal_alpha), strict=True)]
        if not euler_is_stable(e.order, lin, p.h_s):
            return [f'eso: the fal observer is unstable in its linear zone: gains '
                    f'{[float(f"{g:.4g}") for g in lin]} (β·δ^(α−1), δ = {e.fal_delta_mm:g} mm)'
                    f' at h = {p.h_s} s; raise fal_delta_mm or lower the betas']
    if e.discretization == 'euler' and not euler_is_stable(e.order, eso_gains(p), p.h_s):
        bound = _euler_bound(e.order, p.h_s)
        if e.gains == 'bandwidth':
            return [f'eso: explicit-Euler observer with ω0·h = {e.w0_rad_s * p.h_s:.3g} '
                    f'is unstable (bound {bound} for order {e.order})']
        return [f'eso: explicit-Euler observer with betas {list(e.betas)} at h = {p.h_s} s is '
                f'unstable (bandwidth gains are stable up to ω0·h = {bound} for order '
                f'{e.order})']
    return []


def _law_problems(p: ControllerParams) -> list[str]:
    law = p.law
    out = []
    if law.gains == 'explicit' and p.eso.order == 2 and not law.kd > 0.0:
        out.append(f'law.kd must be > 0 for the order-2 law, got {law.kd!r}')
    kp, kd = law_gains(p)
    # nominal loop with a perfect ESO: order 1 e(k+1) = (1 − kp·h)e
    if p.eso.order == 1 and not kp * p.h_s < 1.0:
        out.append(f'law: kp·h = {kp * p.h_s:.3g} >= 1, the sampled loop would overshoot '
                   'every tick; lower law.kp')
    if p.eso.order == 2 and kd > 0.0:
        # order 2: the poles of s² + kd·s + kp must sit well inside the sampling rate
        wn = float(max(abs(np.roots([1.0, kd, kp]))))
        if not wn * p.h_s < 0.25:
            out.append(f'law: the order-2 loop poles reach {wn:.4g} rad/s, ωh = '
                       f'{wn * p.h_s:.3g} >= 0.25 at h = {p.h_s} s: too fast for the sampled '
                       'loop and the axis; lower law.kp/kd (or law.wc_rad_s)')
    return out


def _limit_problems(p: ControllerParams) -> list[str]:
    lim = p.limits
    out = []
    if not lim.soft_z_min_mm < lim.soft_z_max_mm:
        out.append(f'limits.soft_z_min_mm ({lim.soft_z_min_mm:g}) must be below '
                   f'limits.soft_z_max_mm ({lim.soft_z_max_mm:g})')
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


def _follow_problems(p: ControllerParams) -> list[str]:
    f = p.follow
    out = []
    if not f.min_target_gap_mm < f.max_target_gap_mm:
        out.append(f'follow.min_target_gap_mm ({f.min_target_gap_mm:g}) must be below '
                   f'max_target_gap_mm ({f.max_target_gap_mm:g})')
    if not f.collision_gap_mm < f.min_target_gap_mm:
        out.append(f'follow.collision_gap_mm ({f.collision_gap_mm:g}) must be below '
                   f'min_target_gap_mm ({f.min_target_gap_mm:g}): following at the '
                   'collision limit would fault at once')
    if not f.followed_widen_s < f.followed_timeout_s:
        out.append(f'follow.followed_widen_s ({f.followed_widen_s:g}) must be below '
                   f'followed_timeout_s ({f.followed_timeout_s:g}): the tolerance widens '
                   'before the alarm')
    if f.followed_wide_tol_mm < p.pid.followed_tol_mm:
        out.append(f'follow.followed_wide_tol_mm ({f.followed_wide_tol_mm:g}) below '
                   f'pid.followed_tol_mm ({p.pid.followed_tol_mm:g}): widening would '
                   'narrow the tolerance')
    if f.stale_timeout_s < p.h_s:
        out.append(f'follow.stale_timeout_s ({f.stale_timeout_s:g}) below one tick '
                   f'({p.h_s:g} s): every input would be stale')
    return out


VERIFY_LIFT_MIN_MM = 0.02
"""The verification's move up (edge.verify_mm_s x verify_move_s) must lift at least this:
a few times a capacitive sensor's noise, or no fit can tell a gain."""


def _edge_problems(p: ControllerParams) -> list[str]:
    e = p.edge
    out = []
    if e.probe_mm_s < e.judge_mm_s:
        out.append(f'edge.probe_mm_s ({e.probe_mm_s:g}) below edge.judge_mm_s '
                   f'({e.judge_mm_s:g}): closing in after a fast fall could never be judged')
    lift = e.verify_mm_s * e.verify_move_s
    if e.verify_sink > 0.0 and lift < VERIFY_LIFT_MIN_MM:
        out.append(f'edge.verify_mm_s x edge.verify_move_s lifts {lift * 1e3:.3g} µm, below '
                   f'{VERIFY_LIFT_MIN_MM * 1e3:g} µm: the verification could never tell a gain')
    if e.verify_sink > 0.0 and e.verify_move_s < 2.0 * p.h_s:
        out.append(f'edge.verify_move_s ({e.verify_move_s:g}) shorter than two ticks '
                   f'({2.0 * p.h_s:g} s): the move up would not happen')
    return out


# The checks that relate several parameters, run once every value is in its declared range.
CROSS_CHECKS: list[Callable[[ControllerParams], list[str]]] = [
    lambda p: p.td_a.problems(p.h_s, 'td_a.'),
    lambda p: p.td_b.problems(p.h_s, 'td_b.'),
    _eso_problems, _law_problems, _limit_problems, _follow_problems, _edge_problems,
    cnc_problems,
]


def validate(p: ControllerParams) -> list[str]:
    """Return every reason why ``p`` cannot run (empty list: valid).

    First each value against its declaration (:mod:`.schema`), then, if all are in range,
    the cross-parameter checks. A check that raises is itself a reason: validation never
    lets an exception through.
    """
    try:
        out = field_problems(p)
    except Exception as exc:  # noqa: BLE001 - a malformed set is a reason, not a crash
        return [f'parameters could not be checked: {type(exc).__name__}: {exc}']
    if out:
        return out
    for cross in CROSS_CHECKS + EXTRA_VALIDATORS:
        try:
            out += cross(p)
        except Exception as exc:  # noqa: BLE001
            out.append(f'a parameter check failed on these values: {type(exc).__name__}: {exc}')
    return out


def check(p: ControllerParams) -> ControllerParams:
    """Raise :class:`ParameterError` with every reason if ``p`` is invalid; return ``p``."""
    reasons = validate(p)
    if reasons:
        raise ParameterError(reasons)
    return p
