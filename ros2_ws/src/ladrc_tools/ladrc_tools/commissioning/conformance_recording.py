"""What the conformance prober recorded of a driver: the graph, the samples, the plan played.

Plain arrays and dataclasses (no rclpy): the live prober (``ladrc_bringup/conform_node.py``)
fills a :class:`Recording`; the rules (:mod:`.conformance_rules`) judge it. Times are integers
in ns of ROS time (the system clock): ``recv_ns`` is when DDS received a sample (rmw
``received_timestamp``), ``stamp_ns`` the driver's header stamp, ``pub_seq`` the DDS writer's
sequence number of each sample (a jump of ``seq`` that ``pub_seq`` does not share is the driver
skipping a number, a jump both share a sample lost on the way).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
import math
from typing import Any

from ladrc_contract.codes import GapStatus
from ladrc_contract.topics import COMMAND_TOPIC, FEEDBACK_TOPIC, GAP_TOPIC, TOPIC_TYPES
import numpy as np
from scipy import stats

from .excitation import Excitation

H_S = 0.0005
"""The contract's sample period: 2 kHz (seed SAMPLE_PERIOD 2000)."""


CONTRACT_TYPES = {t: TOPIC_TYPES[t] for t in (GAP_TOPIC, FEEDBACK_TOPIC, COMMAND_TOPIC)}


RESET_SERVICE = 'axis/reset_drive'
# CapacitiveHeight.STATUS_* (ladrc_msgs)
STATUS_OK, STATUS_OUT_OF_RANGE, STATUS_COLLISION, STATUS_FAULT = (int(c) for c in GapStatus)

# Segments of a run, in the order the prober plays them (docs/conformance.md, "The run").
PASSIVE, ENABLE, UP, DOWN, EXCITATION, WATCHDOG, SILENCE = (
    'passive', 'enable', 'up', 'down', 'excitation', 'watchdog', 'silence')
# the one-commander test (docs/interfaces.md, "One commander"): a second commander's commands
# while the prober commands zero, the prober's zero alone (the fault must hold), the drive's
# reset service called, the prober's zero again (the drive must be ready)
SECOND_COMMANDER, FAULT_HOLDS, RESET_CALL, AFTER_RESET = (
    'second commander', 'fault holds', 'reset call', 'after reset')


# ---- what the prober recorded ---------------------------------------------------------------
@dataclass(frozen=True)
class Endpoint:
    """One publisher or subscription of the driver on the graph (rclpy endpoint info)."""

    node: str
    type_name: str
    reliability: str  # 'RELIABLE' | 'BEST_EFFORT' | anything else rmw reports
    durability: str   # 'VOLATILE' | 'TRANSIENT_LOCAL' | ...


@dataclass
class Graph:
    """The driver's endpoints by topic (the prober's own left out)."""

    publishers: dict[str, list[Endpoint]] = field(default_factory=dict)
    subscriptions: dict[str, list[Endpoint]] = field(default_factory=dict)


def _i64(values: Any) -> np.ndarray:
    return np.asarray(values, dtype=np.int64).reshape(-1)


@dataclass(kw_only=True)
class Samples:
    """One received topic, in arrival order (every array one entry per sample)."""

    recv_ns: np.ndarray
    stamp_ns: np.ndarray
    seq: np.ndarray
    pub_seq: np.ndarray | None = None  # None: the middleware gave none

    def __post_init__(self) -> None:
        self.recv_ns, self.stamp_ns, self.seq = (_i64(self.recv_ns), _i64(self.stamp_ns),
                                                 _i64(self.seq))
        if self.pub_seq is not None:
            self.pub_seq = _i64(self.pub_seq)
            if len(self.pub_seq) != len(self.recv_ns) or not np.all(self.pub_seq > 0):
                self.pub_seq = None  # unknown (rmw reports 0 where unsupported)

    def __len__(self) -> int:
        return len(self.recv_ns)

    def window(self, start_ns: int, end_ns: int) -> np.ndarray:
        """Return the mask of the samples received in ``[start_ns, end_ns]``."""
        return (self.recv_ns >= start_ns) & (self.recv_ns <= end_ns)

    def since(self, start_ns: int) -> Samples:
        """Return a copy holding only the samples received at or after ``start_ns``."""
        keep = self.recv_ns >= start_ns
        kw: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None or isinstance(v, np.ndarray):
                kw[f.name] = None if v is None else v[keep]
            else:
                kw[f.name] = [x for x, k in zip(v, keep, strict=True) if k]
        return type(self)(**kw)


@dataclass(kw_only=True)
class GapSamples(Samples):
    """``axis/capacitive_height`` as received."""

    gap_mm: np.ndarray
    valid: np.ndarray
    status: np.ndarray

    def __post_init__(self) -> None:
        super().__post_init__()
        self.gap_mm = np.asarray(self.gap_mm, dtype=float).reshape(-1)
        self.valid = np.asarray(self.valid, dtype=bool).reshape(-1)
        self.status = np.asarray(self.status, dtype=np.int64).reshape(-1)


@dataclass(kw_only=True)
class FeedbackSamples(Samples):
    """``axis/feedback`` as received."""

    position_mm: np.ndarray
    velocity_mm_s: np.ndarray
    drive_enabled: np.ndarray
    drive_fault: np.ndarray
    fault_reason: list[str]

    def __post_init__(self) -> None:
        super().__post_init__()
        self.position_mm = np.asarray(self.position_mm, dtype=float).reshape(-1)
        self.velocity_mm_s = np.asarray(self.velocity_mm_s, dtype=float).reshape(-1)
        self.drive_enabled = np.asarray(self.drive_enabled, dtype=bool).reshape(-1)
        self.drive_fault = np.asarray(self.drive_fault, dtype=bool).reshape(-1)
        self.fault_reason = [str(r) for r in self.fault_reason]


@dataclass(frozen=True)
class Segment:
    """One part of the run: what the prober commanded from ``start_ns`` to ``end_ns``.

    ``velocity_mm_s`` is the nominal command (the excitation's amplitude for that segment);
    ``commanded`` is False where the prober sent nothing (passive, the watchdog's silence).
    """

    name: str
    start_ns: int
    end_ns: int
    velocity_mm_s: float = 0.0
    enable: bool = False
    commanded: bool = True


@dataclass
class BagCheck:
    """The motion-test bag read back after closing: per-topic counts vs what was recorded."""

    path: str
    readable: bool
    error: str = ''
    counts: dict[str, int] = field(default_factory=dict)    # in the bag, by topic
    expected: dict[str, int] = field(default_factory=dict)  # handed to the writer, by topic
    dropped: int = 0                                         # the writer's full-queue drops


@dataclass(frozen=True)
class Plan:
    """The motion tests: bounds (safety) and the commanded profile (docs/conformance.md).

    The prober never commands more than ``max_speed_mm_s``, aborts (zero command, enable
    false) when the encoder leaves ``±max_travel_mm`` around its start, when the axis moves
    faster than ``max_speed_mm_s``, when a gap reading is below ``min_gap_mm`` (or invalid),
    when either topic has been silent for ``stale_s``, or on a drive fault while commanding.
    After an abort for stale data or a drive fault (what a stall of the host causes: a
    5 ms gap in the commands trips the drive's watchdog) it tries the motion tests once more,
    from rest and within the same bounds around the first start (``retries``).
    """

    min_gap_mm: float = 2.0
    max_travel_mm: float = 2.0
    max_speed_mm_s: float = 8.0
    test_speed_mm_s: float = 2.0
    test_travel_mm: float = 1.0
    passive_s: float = 1.0
    enable_s: float = 0.3
    settle_s: float = 0.2
    watchdog_run_s: float = 0.3
    watch_s: float = 0.2
    stale_s: float = 0.1
    abort_hold_s: float = 0.3
    retries: int = 1
    excitation: Excitation | None = Excitation(kind='prbs', amplitude_mm_s=4.0,
                                               max_travel_mm=0.5, f_low_hz=1.0,
                                               f_high_hz=100.0, duration_s=2.0, seed=1)

    @property
    def half_s(self) -> float:
        """Duration of each half (up, down) of the units-and-signs test."""
        return self.test_travel_mm / self.test_speed_mm_s

    def problems(self) -> list[str]:
        """Return every reason the plan is unsafe or unusable (empty: ok)."""
        out = []
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == 'excitation':
                continue
            if f.name == 'retries':
                if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 3:
                    out.append(f'retries = {v!r}: an integer in 0..3 is required')
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or v <= 0:
                out.append(f'{f.name} = {v!r}: a finite number > 0 is required')
        if out:
            return out
        if self.test_speed_mm_s > 0.5 * self.max_speed_mm_s:
            out.append(f'test_speed_mm_s = {self.test_speed_mm_s:g} must be at most half of '
                       f'max_speed_mm_s = {self.max_speed_mm_s:g} (room for overshoot before '
                       'the speed bound aborts)')
        if self.test_travel_mm > 0.5 * self.max_travel_mm:
            out.append(f'test_travel_mm = {self.test_travel_mm:g} must be at most half of '
                       f'max_travel_mm = {self.max_travel_mm:g} (the watchdog run-up and the '
                       'coasting add to it)')
        if self.test_speed_mm_s * self.watchdog_run_s > 0.5 * self.max_travel_mm:
            out.append('the watchdog run-up (test_speed_mm_s x watchdog_run_s) must stay below '
                       'half of max_travel_mm')
        if self.half_s < 0.1:
            out.append(f'test_travel_mm / test_speed_mm_s = {self.half_s:g} s: each half of '
                       'the units test needs at least 0.1 s to measure a speed')
        if self.stale_s < 2 * H_S:
            out.append(f'stale_s = {self.stale_s:g} is below two sample periods')
        if self.stale_s * self.max_speed_mm_s > 0.5 * self.max_travel_mm:
            out.append(f'stale_s x max_speed_mm_s = {self.stale_s * self.max_speed_mm_s:g} mm: '
                       'the axis could travel more than half of max_travel_mm before stale '
                       'data stop the test')
        ex = self.excitation
        if ex is not None:
            out += [f'excitation: {p}' for p in ex.problems(H_S)]
            if ex.amplitude_mm_s > 0.75 * self.max_speed_mm_s:
                out.append(f'excitation amplitude {ex.amplitude_mm_s:g} mm/s must stay below '
                           f'0.75 x max_speed_mm_s = {0.75 * self.max_speed_mm_s:g}')
            if ex.max_travel_mm > 0.5 * self.max_travel_mm:
                out.append(f'excitation max_travel_mm {ex.max_travel_mm:g} must be at most half '
                           f'of max_travel_mm = {self.max_travel_mm:g} (the axis lags the '
                           'profile)')
        return out

    def as_dict(self) -> dict[str, Any]:
        """Return the plan as a JSON-friendly dict."""
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != 'excitation'}
        d['excitation'] = asdict(self.excitation) if self.excitation is not None else None
        return d


@dataclass
class Recording:
    """Everything one run of the prober saw and sent (the input of :func:`evaluate`)."""

    graph: Graph
    gap: GapSamples
    feedback: FeedbackSamples
    command_send_ns: np.ndarray
    command_velocity_mm_s: np.ndarray
    command_enable: np.ndarray
    segments: list[Segment]
    plan: Plan = field(default_factory=Plan)
    aborted: str = ''   # why the prober stopped the motion tests ('' = it did not)
    not_run: str = ''   # why the motion tests were never started ('' = they were)
    notes: list[str] = field(default_factory=list)
    bag: BagCheck | None = None
    commander: str = ''  # the prober's commander name (VelocityCommand.commander)
    second_commander: str = ''  # the name the second commander's commands carried
    second_send_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    reset_answer: str = ''  # what the drive's reset service answered ('' = not called)

    def __post_init__(self) -> None:
        self.command_send_ns = _i64(self.command_send_ns)
        self.command_velocity_mm_s = np.asarray(self.command_velocity_mm_s,
                                                dtype=float).reshape(-1)
        self.command_enable = np.asarray(self.command_enable, dtype=bool).reshape(-1)
        self.second_send_ns = _i64(self.second_send_ns)

    def segment(self, name: str) -> Segment | None:
        """Return the segment called ``name`` (None: not played)."""
        return next((s for s in self.segments if s.name == name), None)

    def why_missing(self, *names: str) -> str:
        """Return the reason a motion segment is missing (abort, not run, or not planned)."""
        missing = [n for n in names if self.segment(n) is None]
        if not missing:
            return ''
        why = self.aborted or self.not_run or 'not in the plan'
        return f'not run ({", ".join(missing)}): {why}'


def median_period_s(s: Samples) -> float:
    """Return the median interval between receptions (the contract's period if too few)."""
    if len(s) < 3:
        return H_S
    d = np.diff(s.recv_ns)
    d = d[d > 0]
    return float(np.median(d)) * 1e-9 if len(d) else H_S


def fit_slope(t_ns: np.ndarray, y: np.ndarray) -> float:
    """Return dy/dt per second (least squares, scipy.stats.linregress)."""
    if len(t_ns) < 5 or np.ptp(t_ns) <= 0:
        return math.nan
    t = (t_ns - t_ns[0]) * 1e-9
    return float(stats.linregress(t, y).slope)
