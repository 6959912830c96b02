"""Driver conformance rules (issue 15 item 1): recorded samples in, pass/fail + figure out.

Pure (no rclpy): the live prober (``ladrc_tools/node/conform_node.py``) records what it saw of
a driver on the ROS graph into the plain arrays and dataclasses of this module (a
:class:`Recording`), and :func:`evaluate` judges it rule by rule against the contract
(docs/interfaces.md) with the documented tolerances of :class:`Tolerances`. Every rule gives
its measured figure and a one-line reason; docs/conformance.md lists the rules.

Times are integers in ns of ROS time (the system clock): ``recv_ns`` is when DDS received a
sample (rmw ``received_timestamp``, taken on the middleware's own thread, so the prober's
Python loop does not add to it), ``stamp_ns`` the driver's header stamp. ``pub_seq`` is the DDS
writer's sequence number of each sample (rmw ``publication_sequence_number``): it grows by one
per sample *written*, so a jump of ``seq`` that ``pub_seq`` does not share is the driver
skipping a number, and a jump both share is a sample lost on the way.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
import math
from typing import Any, Callable

from ladrc_contract.codes import GapStatus
import numpy as np
from scipy import stats

from .excitation import Excitation

H_S = 0.0005
"""The contract's sample period: 2 kHz (seed SAMPLE_PERIOD 2000)."""

GAP_TOPIC = 'axis/capacitive_height'
FEEDBACK_TOPIC = 'axis/feedback'
COMMAND_TOPIC = 'axis/velocity_command'
CONTRACT_TYPES = {
    GAP_TOPIC: 'ladrc_msgs/msg/CapacitiveHeight',
    FEEDBACK_TOPIC: 'ladrc_msgs/msg/AxisFeedback',
    COMMAND_TOPIC: 'ladrc_msgs/msg/VelocityCommand',
}
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
RESET_SERVICE = 'axis/reset_drive'


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


def empty_gap() -> GapSamples:
    """Return a topic with no sample (nothing received)."""
    return GapSamples(recv_ns=[], stamp_ns=[], seq=[], gap_mm=[], valid=[], status=[])


def empty_feedback() -> FeedbackSamples:
    """Return a topic with no sample (nothing received)."""
    return FeedbackSamples(recv_ns=[], stamp_ns=[], seq=[], position_mm=[], velocity_mm_s=[],
                           drive_enabled=[], drive_fault=[], fault_reason=[])


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


# ---- tolerances ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Tolerances:
    """The documented tolerance of each rule (docs/conformance.md says why each)."""

    rate_hz: float = 2000.0                 # the contract's rate
    rate_rel: float = 0.05                  # rate within ±5 %
    period_p99_s: float = 0.0015            # arrival period p99 <= 3 sample periods
    future_s: float = 0.001                 # stamp at most 1 ms after its reception
    age_median_s: float = 0.002             # reception - stamp, median: 4 sample periods
    age_limit_s: float = 0.010              # older than this the controller rejects a sample
    age_late_share: float = 0.05            # ... which may happen to at most 5 % of them
    enable_travel_mm: float = 0.02          # travel allowed while enable is false
    speed_rel: float = 0.10                 # measured speed / commanded within ±10 %
    velocity_rel: float = 0.10              # reported velocity / encoder slope within ±10 %
    gap_slope_rel: float = 0.10             # d(gap)/d(encoder) within 1 ± 10 %
    watchdog_timeout_s: float = 0.005       # docs/safety.md: 5 ms without a command
    watchdog_allowance_s: float = 0.002     # + the command's transport and the drive's cycle
    stop_allowance_s: float = 0.010         # braking to rest after the watchdog trips
    rest_mm: float = 0.005                  # "at rest": within 5 µm (5 encoder counts)
    commander_fault_s: float = 0.0025       # a second commander: the next drive cycle (0.5 ms)
    #                                         + the watchdog's transport allowance (2 ms)

    def as_dict(self) -> dict[str, float]:
        """Return the tolerances as a JSON-friendly dict."""
        return asdict(self)


# ---- results ------------------------------------------------------------------------------
@dataclass
class RuleResult:
    """The verdict of one rule: pass/fail, the measured figure and a one-line reason."""

    name: str
    passed: bool
    figure: float | None
    unit: str
    reason: str
    tolerance: str = ''

    def as_dict(self) -> dict[str, Any]:
        """Return the result as a JSON-friendly dict (a non-finite figure as None)."""
        fig = self.figure
        if fig is not None and not math.isfinite(fig):
            fig = None
        return {'name': self.name, 'passed': bool(self.passed), 'figure': fig,
                'unit': self.unit, 'reason': self.reason, 'tolerance': self.tolerance}


@dataclass
class ConformanceResult:
    """All rules of one run; ``passed`` only when every rule passed."""

    results: list[RuleResult]
    aborted: str = ''
    not_run: str = ''
    notes: list[str] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        """Whether every rule passed."""
        return bool(self.results) and all(r.passed for r in self.results)

    @property
    def rules_failed(self) -> list[str]:
        """Names of the rules that failed."""
        return [r.name for r in self.results if not r.passed]

    @property
    def rules_passed(self) -> list[str]:
        """Names of the rules that passed."""
        return [r.name for r in self.results if r.passed]

    def __getitem__(self, name: str) -> RuleResult:
        for r in self.results:
            if r.name == name:
                return r
        raise KeyError(name)

    def summary(self) -> str:
        """Return one line per failed rule (or 'all N rules passed')."""
        if self.passed:
            return f'all {len(self.results)} rules passed'
        return '\n'.join(f'{r.name}: {r.reason}' for r in self.results if not r.passed)

    def as_dict(self) -> dict[str, Any]:
        """Return the result as a JSON-friendly dict (conform.json)."""
        return {'passed': self.passed, 'rules_passed': len(self.rules_passed),
                'rules_failed': self.rules_failed, 'rules_total': len(self.results),
                'aborted': self.aborted, 'not_run': self.not_run, 'notes': list(self.notes),
                'rules': [r.as_dict() for r in self.results], **self.extra}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ConformanceResult:
        """Rebuild a result from :meth:`as_dict` (conform.json)."""
        results = [RuleResult(name=r['name'], passed=bool(r['passed']),
                              figure=None if r.get('figure') is None else float(r['figure']),
                              unit=r.get('unit', ''), reason=r.get('reason', ''),
                              tolerance=r.get('tolerance', '')) for r in data['rules']]
        known = {'passed', 'rules_passed', 'rules_failed', 'rules_total', 'aborted', 'not_run',
                 'notes', 'rules'}
        return cls(results, data.get('aborted', ''), data.get('not_run', ''),
                   list(data.get('notes', [])),
                   {k: v for k, v in data.items() if k not in known})


# ---- helpers --------------------------------------------------------------------------------
def _ms(seconds: float) -> str:
    return f'{seconds * 1e3:.3g} ms'


def _result(name: str, ok: bool, figure: float | None, unit: str, reason: str) -> RuleResult:
    return RuleResult(name, bool(ok), None if figure is None else float(figure), unit,
                      ' '.join(reason.split()))


def _fail(name: str, unit: str, reason: str) -> RuleResult:
    return _result(name, False, None, unit, reason)


def compatible(writer: Endpoint, reader: Endpoint) -> tuple[bool, str]:
    """Return whether ``reader`` receives from ``writer``: DDS request-vs-offered matching.

    A BEST_EFFORT reader matches any writer; a RELIABLE reader only a RELIABLE writer. A
    VOLATILE reader matches any writer; a TRANSIENT_LOCAL reader only a TRANSIENT_LOCAL one.
    """
    rel_rank = {'BEST_EFFORT': 0, 'RELIABLE': 1}
    dur_rank = {'VOLATILE': 0, 'TRANSIENT_LOCAL': 1}
    why = []
    if rel_rank.get(reader.reliability, 1) > rel_rank.get(writer.reliability, 0):
        why.append(f'a {reader.reliability} reader does not match a {writer.reliability} '
                   'writer')
    if dur_rank.get(reader.durability, 1) > dur_rank.get(writer.durability, 0):
        why.append(f'a {reader.durability} reader does not match a {writer.durability} writer')
    return not why, '; '.join(why)


# The contract's endpoints (docs/interfaces.md, QoS; ladrc_follow/node/qos.py).
CONTRACT_READER = Endpoint('controller', '', 'BEST_EFFORT', 'VOLATILE')
CONTRACT_WRITER = Endpoint('controller', '', 'BEST_EFFORT', 'VOLATILE')


def _median_period_s(s: Samples) -> float:
    if len(s) < 3:
        return H_S
    d = np.diff(s.recv_ns)
    d = d[d > 0]
    return float(np.median(d)) * 1e-9 if len(d) else H_S


def _fit_slope(t_ns: np.ndarray, y: np.ndarray) -> float:
    """Return dy/dt per second (least squares, scipy.stats.linregress)."""
    if len(t_ns) < 5 or np.ptp(t_ns) <= 0:
        return math.nan
    t = (t_ns - t_ns[0]) * 1e-9
    return float(stats.linregress(t, y).slope)


def _topics(rec: Recording) -> list[tuple[str, Samples]]:
    """Return both sample topics from the passive window on (the stream rules' data).

    The first deliveries after the reader matched carry whatever the middleware had queued
    (seen: a stale sample, then a 333 ms gap and a jump of 411 in seq); they say nothing about
    the driver, so the stream is judged from the passive window on (the prober starts it once
    the stream is steady).
    """
    seg = rec.segment(PASSIVE)
    if seg is None:
        return [(GAP_TOPIC, rec.gap), (FEEDBACK_TOPIC, rec.feedback)]
    return [(GAP_TOPIC, rec.gap.since(seg.start_ns)),
            (FEEDBACK_TOPIC, rec.feedback.since(seg.start_ns))]


# ---- the rules ------------------------------------------------------------------------------
def rule_topics_types(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that the driver publishes both sample topics and subscribes the command."""
    problems = []
    for topic, kind, eps in ((GAP_TOPIC, 'publisher', rec.graph.publishers.get(GAP_TOPIC, [])),
                             (FEEDBACK_TOPIC, 'publisher',
                              rec.graph.publishers.get(FEEDBACK_TOPIC, [])),
                             (COMMAND_TOPIC, 'subscription',
                              rec.graph.subscriptions.get(COMMAND_TOPIC, []))):
        want = CONTRACT_TYPES[topic]
        if not eps:
            problems.append(f'no {kind} on {topic}')
            continue
        wrong = sorted({e.type_name for e in eps if e.type_name != want})
        if wrong:
            problems.append(f'{topic} has type {", ".join(wrong)} (contract: {want})')
        if kind == 'publisher' and len(eps) > 1:
            problems.append(f'{len(eps)} publishers on {topic} '
                            f'({", ".join(e.node for e in eps)}): their samples interleave')
    others = rec.graph.publishers.get(COMMAND_TOPIC, [])
    if others:
        problems.append(f'another node publishes {COMMAND_TOPIC} '
                        f'({", ".join(e.node for e in others)}): stop it before the tests')
    ok = not problems
    return _result('topics_types', ok, len(problems), 'problems',
                   'both sample topics published and the command subscribed with the contract '
                   'types' if ok else '; '.join(problems))


def rule_qos_publishers(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that the sample publishers are BEST_EFFORT, VOLATILE as the contract's."""
    bad = []
    n = 0
    for topic in (GAP_TOPIC, FEEDBACK_TOPIC):
        for e in rec.graph.publishers.get(topic, []):
            n += 1
            ok, why = compatible(e, CONTRACT_READER)
            if not ok:
                bad.append(f'{topic} ({e.node}): the controller never receives it: {why}')
            elif e.reliability != 'BEST_EFFORT':
                bad.append(f'{topic} ({e.node}) is {e.reliability}: the contract is '
                           'BEST_EFFORT (reliable writers at 2 kHz lost 7-50 % to the '
                           'recorder on a loaded machine, docs/interfaces.md)')
            elif e.durability != 'VOLATILE':
                bad.append(f'{topic} ({e.node}) is {e.durability}: the contract is VOLATILE '
                           '(a late reader must not get stale samples)')
    if n == 0:
        return _fail('qos_publishers', 'publishers', 'no publisher of the sample topics found')
    return _result('qos_publishers', not bad, len(bad), 'publishers off-contract',
                   f'{n} publisher(s) BEST_EFFORT, VOLATILE as the contract' if not bad
                   else '; '.join(bad))


def rule_qos_command_input(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that the driver's command subscription receives best-effort commands."""
    subs = rec.graph.subscriptions.get(COMMAND_TOPIC, [])
    if not subs:
        return _fail('qos_command_input', 'subscriptions', f'no subscription on {COMMAND_TOPIC}')
    bad = []
    for e in subs:
        ok, why = compatible(CONTRACT_WRITER, e)
        if not ok:
            bad.append(f"{e.node}: the controller's BEST_EFFORT, VOLATILE commands never "
                       f'arrive ({why})')
    return _result('qos_command_input', not bad, len(bad), 'subscriptions incompatible',
                   f'{len(subs)} subscription(s) match a BEST_EFFORT, VOLATILE writer'
                   if not bad else '; '.join(bad))


def _rate(s: Samples) -> tuple[float, int]:
    """Return (samples per second the driver wrote, samples lost on the way)."""
    if len(s) < 2 or s.recv_ns[-1] <= s.recv_ns[0]:
        return 0.0, 0
    span_s = (s.recv_ns[-1] - s.recv_ns[0]) * 1e-9
    if s.pub_seq is not None:
        written = int(s.pub_seq[-1] - s.pub_seq[0])
        return written / span_s, max(0, written + 1 - len(s))
    return (len(s) - 1) / span_s, 0


def rule_rate(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that each sample topic arrives at 2 kHz (writes over the reception span)."""
    parts, worst, ok = [], math.nan, True
    for topic, s in _topics(rec):
        rate, lost = _rate(s)
        dev = abs(rate - tol.rate_hz) / tol.rate_hz
        if not dev <= tol.rate_rel:
            ok = False
        if math.isnan(worst) or dev > abs(worst - tol.rate_hz) / tol.rate_hz:
            worst = rate
        parts.append(f'{topic} {rate:.0f} Hz ({len(s)} received, {lost} lost in transport)')
    return _result('rate', ok, worst, 'Hz', '; '.join(parts))


def rule_jitter(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check the arrival period (what the controller sees): p99 <= 3 sample periods."""
    parts, worst, ok = [], 0.0, True
    for topic, s in _topics(rec):
        if len(s) < 100:
            ok = False
            parts.append(f'{topic}: {len(s)} samples, too few to judge')
            continue
        d = np.diff(s.recv_ns) * 1e-9
        p99 = float(np.percentile(d, 99))
        st = np.diff(s.stamp_ns) * 1e-9
        worst = max(worst, p99)
        ok = ok and p99 <= tol.period_p99_s
        parts.append(f'{topic} arrival p99 {_ms(p99)} (max {_ms(float(d.max()))}; stamps p99 '
                     f'{_ms(float(np.percentile(st, 99)))})')
    return _result('jitter', ok, worst * 1e3, 'ms', '; '.join(parts))


def rule_seq_increments(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that ``seq`` grows by one per sample written: no skipped or repeated numbers."""
    parts, total, ok = [], 0, True
    for topic, s in _topics(rec):
        if len(s) < 2:
            ok = False
            parts.append(f'{topic}: nothing to judge ({len(s)} samples)')
            continue
        ds = np.diff(s.seq)
        if s.pub_seq is not None:
            expected = np.diff(s.pub_seq)
            how = 'vs the DDS writer sequence'
        else:
            expected = np.ones_like(ds)
            how = 'no DDS sequence: transport loss counts too'
        wrong = np.flatnonzero(ds != expected)
        total += len(wrong)
        ok = ok and not len(wrong)
        example = (f'; first {int(s.seq[wrong[0]])} -> {int(s.seq[wrong[0] + 1])}'
                   if len(wrong) else '')
        parts.append(f'{topic}: {len(wrong)} of {len(ds)} steps wrong ({how}{example})')
    return _result('seq_increments', ok, total, 'wrong steps', '; '.join(parts))


def rule_stamps_monotonic(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that header stamps strictly increase, sample after sample."""
    parts, total, ok = [], 0, True
    for topic, s in _topics(rec):
        if len(s) < 2:
            ok = False
            parts.append(f'{topic}: nothing to judge')
            continue
        bad = int(np.count_nonzero(np.diff(s.stamp_ns) <= 0))
        total += bad
        ok = ok and bad == 0
        parts.append(f'{topic}: {bad} non-increasing of {len(s) - 1}')
    return _result('stamps_monotonic', ok, total, 'steps', '; '.join(parts))


def rule_stamps_not_future(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that no stamp lies after its own reception (beyond a clock-offset allowance)."""
    parts, worst, ok = [], -math.inf, True
    for topic, s in _topics(rec):
        if not len(s):
            ok = False
            parts.append(f'{topic}: nothing received')
            continue
        lead = float(np.max(s.stamp_ns - s.recv_ns)) * 1e-9
        n = int(np.count_nonzero((s.stamp_ns - s.recv_ns) * 1e-9 > tol.future_s))
        worst = max(worst, lead)
        ok = ok and lead <= tol.future_s
        parts.append(f'{topic}: stamp - reception max {_ms(lead)} ({n} samples beyond)')
    return _result('stamps_not_future', ok, worst * 1e3 if math.isfinite(worst) else None, 'ms',
                   '; '.join(parts))


def rule_stamp_age(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check reception minus stamp (latch to arrival): median, and the share too old to use.

    The median is the driver's systematic latency (it adds to the loop's dead time); the
    share older than the controller's ``stamp_tolerance_s`` (10 ms) is what it would throw
    away. A stall of the host delivers a backlog at once (seen: 250 ms once in a 6 s run on a
    loaded 2-core VM), so a high percentile is no fair test of a short run.
    """
    parts, worst, ok = [], 0.0, True
    for topic, s in _topics(rec):
        if not len(s):
            ok = False
            parts.append(f'{topic}: nothing received')
            continue
        age = (s.recv_ns - s.stamp_ns) * 1e-9
        med = float(np.median(age))
        late = float(np.mean(age > tol.age_limit_s))
        worst = max(worst, med)
        ok = ok and med <= tol.age_median_s and late <= tol.age_late_share
        parts.append(f'{topic}: age median {_ms(med)}, p99 {_ms(float(np.percentile(age, 99)))}'
                     f', {late * 100:.3g} % older than {_ms(tol.age_limit_s)}')
    return _result('stamp_age', ok, worst * 1e3, 'ms', '; '.join(parts))


def rule_drive_ready(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check, before any command: drive enabled, no fault, valid readings above the minimum."""
    seg = rec.segment(PASSIVE)
    if seg is None:
        return _fail('drive_ready', 'mm', rec.not_run or 'no passive window recorded')
    fb, gp = rec.feedback, rec.gap
    mf, mg = fb.window(seg.start_ns, seg.end_ns), gp.window(seg.start_ns, seg.end_ns)
    if not mf.any() or not mg.any():
        return _fail('drive_ready', 'mm', 'no samples in the passive window '
                     f'({int(mf.sum())} feedback, {int(mg.sum())} gap)')
    problems = []
    if not fb.drive_enabled[mf].all():
        problems.append('drive_enabled false')
    if fb.drive_fault[mf].any():
        i = int(np.flatnonzero(mf & fb.drive_fault)[0])
        problems.append(f'drive_fault true ({fb.fault_reason[i] or "no reason given"})')
    reasons = [fb.fault_reason[i] for i in np.flatnonzero(mf & ~fb.drive_fault)]
    if any(reasons):
        problems.append(f'fault_reason {next(r for r in reasons if r)!r} without drive_fault')
    g = gp.gap_mm[mg]
    if not (gp.valid[mg].all() and (gp.status[mg] == STATUS_OK).all()):
        problems.append(f'{int((~gp.valid[mg]).sum())} invalid readings (status '
                        f'{sorted(set(gp.status[mg].tolist()))})')
    gmin = float(np.min(g)) if np.isfinite(g).all() else math.nan
    if not gmin >= rec.plan.min_gap_mm:
        problems.append(f'gap {gmin:.3g} mm below the minimum {rec.plan.min_gap_mm:g} mm')
    return _result('drive_ready', not problems, gmin, 'mm',
                   f'enabled, no fault, gap {gmin:.4g} mm >= {rec.plan.min_gap_mm:g} mm'
                   if not problems else '; '.join(problems))


def rule_enable_false_holds(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that commands with enable=false (an upward velocity) do not move the axis."""
    seg = rec.segment(ENABLE)
    if seg is None:
        return _fail('enable_false_holds', 'mm', rec.why_missing(ENABLE))
    fb = rec.feedback
    m = fb.window(seg.start_ns, seg.end_ns + int(0.02e9))
    if m.sum() < 10:
        return _fail('enable_false_holds', 'mm', 'too few feedback samples in the test')
    p = fb.position_mm[m]
    travel = float(np.max(np.abs(p - p[0])))
    ok = travel <= tol.enable_travel_mm
    return _result('enable_false_holds', ok, travel, 'mm',
                   f'travel {travel:.4g} mm while {seg.velocity_mm_s:g} mm/s was commanded with '
                   f'enable=false for {(seg.end_ns - seg.start_ns) * 1e-9:.3g} s'
                   + ('' if ok else ' (the drive must hold zero whatever velocity_mm_s says)'))


def _halves(rec: Recording) -> list[tuple[Segment, np.ndarray]] | str:
    """Return the up and down halves with the feedback mask of their steady part."""
    out = []
    for name in (UP, DOWN):
        seg = rec.segment(name)
        if seg is None:
            return rec.why_missing(UP, DOWN)
        # the steady part: skip the first 30 % (the velocity loop's lag, the dead time)
        start = seg.start_ns + int(0.3 * (seg.end_ns - seg.start_ns))
        m = rec.feedback.window(start, seg.end_ns)
        if m.sum() < 20:
            return f'too few feedback samples in the {name} half ({int(m.sum())})'
        out.append((seg, m))
    return out


def rule_motion_direction(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that, commanded up then down, the encoder moves up then down (Z up)."""
    halves = _halves(rec)
    if isinstance(halves, str):
        return _fail('motion_direction', 'ratio', halves)
    fb = rec.feedback
    parts, worst, ok = [], math.inf, True
    for seg, m in halves:
        slope = _fit_slope(fb.recv_ns[m], fb.position_mm[m])
        ratio = slope / seg.velocity_mm_s
        worst = min(worst, ratio)
        # moved, and the way it was told (a tenth of the commanded speed at least)
        good = ratio >= 0.1
        ok = ok and good
        word = 'up' if slope > 0 else 'down'
        parts.append(f'{seg.name}: commanded {seg.velocity_mm_s:+g} mm/s, encoder moved {word} '
                     f'at {slope:+.3g} mm/s' + ('' if good else ' (WRONG)' if ratio < -0.1
                                                else ' (did not move)'))
    return _result('motion_direction', ok, worst, 'ratio', '; '.join(parts))


def rule_motion_speed(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that the encoder's speed equals the commanded speed (b0 = 1) within ±10 %."""
    halves = _halves(rec)
    if isinstance(halves, str):
        return _fail('motion_speed', 'ratio', halves)
    fb = rec.feedback
    parts, worst, ok = [], 1.0, True
    for seg, m in halves:
        ratio = abs(_fit_slope(fb.recv_ns[m], fb.position_mm[m]) / seg.velocity_mm_s)
        if not abs(ratio - 1.0) <= abs(worst - 1.0):
            worst = ratio
        ok = ok and abs(ratio - 1.0) <= tol.speed_rel
        parts.append(f'{seg.name}: |encoder speed| / |command| = {ratio:.4g}')
    return _result('motion_speed', ok, worst, 'ratio', '; '.join(parts))


def rule_velocity_feedback(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check ``AxisFeedback.velocity_mm_s`` against the encoder's own slope (mm/s, sign)."""
    halves = _halves(rec)
    if isinstance(halves, str):
        return _fail('velocity_feedback', 'ratio', halves)
    fb = rec.feedback
    parts, worst, ok = [], 1.0, True
    for seg, m in halves:
        slope = _fit_slope(fb.recv_ns[m], fb.position_mm[m])
        reported = float(np.mean(fb.velocity_mm_s[m]))
        ratio = reported / slope if slope != 0 and math.isfinite(slope) else math.nan
        if not abs(ratio - 1.0) <= abs(worst - 1.0):
            worst = ratio
        ok = ok and abs(ratio - 1.0) <= tol.velocity_rel
        parts.append(f'{seg.name}: reported {reported:+.4g} mm/s, encoder {slope:+.4g} mm/s')
    return _result('velocity_feedback', ok, worst, 'ratio', '; '.join(parts))


def rule_gap_tracks_encoder(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that over the flat sheet the gap reading changes as the encoder: d(gap)/dz = 1."""
    up, down = rec.segment(UP), rec.segment(DOWN)
    if up is None or down is None:
        return _fail('gap_tracks_encoder', 'mm/mm', rec.why_missing(UP, DOWN))
    fb, gp = rec.feedback, rec.gap
    mg = gp.window(up.start_ns, down.end_ns) & gp.valid & np.isfinite(gp.gap_mm)
    order = np.argsort(fb.recv_ns, kind='stable')
    if mg.sum() < 20 or len(fb) < 2:
        return _fail('gap_tracks_encoder', 'mm/mm',
                     f'too few valid gap readings ({int(mg.sum())})')
    z = np.interp(gp.recv_ns[mg], fb.recv_ns[order], fb.position_mm[order])
    if np.ptp(z) < 0.2 * rec.plan.test_travel_mm:
        return _fail('gap_tracks_encoder', 'mm/mm', f'the encoder moved only {np.ptp(z):.3g} mm: '
                     'nothing to compare the reading with')
    fit = stats.linregress(z, gp.gap_mm[mg])
    slope = float(fit.slope)
    ok = abs(slope - 1.0) <= tol.gap_slope_rel
    hint = ''
    if not ok:
        if slope < 0:
            hint = ' (the reading falls as the axis rises: sign)'
        elif 500 < slope < 2000:
            hint = ' (x1000: the reading is in µm, not mm)'
        else:
            hint = ' (units, calibration table, or not a flat resting sheet)'
    return _result('gap_tracks_encoder', ok, slope, 'mm/mm',
                   f'gap reading vs encoder over {np.ptp(z):.3g} mm of travel: slope {slope:.4g}, '
                   f'residual {float(np.std(gp.gap_mm[mg] - fit.intercept - slope * z)):.2g} mm'
                   + hint)


def _watch(rec: Recording) -> tuple[Segment, Segment, np.ndarray] | str:
    run, silence = rec.segment(WATCHDOG), rec.segment(SILENCE)
    if run is None or silence is None:
        return rec.why_missing(WATCHDOG, SILENCE)
    fb = rec.feedback
    # The samples the drive published after the last command: reception minus the median
    # latch-to-arrival age (when positive: a stamp in the future says nothing about transport).
    age_ns = int(max(0.0, float(np.median(fb.recv_ns - fb.stamp_ns)))) if len(fb) else 0
    idx = np.flatnonzero(fb.window(silence.start_ns + 1 + age_ns, silence.end_ns))
    if len(idx) < 5:
        return f'too few feedback samples after the last command ({len(idx)})'
    return run, silence, idx


def rule_watchdog_fault(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that when commands stop, ``drive_fault`` comes with a reason within the timeout.

    Latency in the drive's own cycles (samples by ``seq`` from the first one it published
    after the last command: reception minus the median latch-to-arrival age), times its median
    period: the watchdog counts cycles, as the sim's and a fieldbus drive's do, so a stall of
    the prober's machine does not count against it.
    """
    w = _watch(rec)
    if isinstance(w, str):
        return _fail('watchdog_fault', 'ms', w)
    run, silence, idx = w
    fb = rec.feedback
    before = fb.window(run.start_ns, run.end_ns) & fb.drive_fault
    if before.any():
        i = int(np.flatnonzero(before)[0])
        return _fail('watchdog_fault', 'ms', 'drive fault while commands were still coming '
                     f'({fb.fault_reason[i] or "no reason"})')
    faulted = idx[fb.drive_fault[idx]]
    bar = tol.watchdog_timeout_s + tol.watchdog_allowance_s
    if not len(faulted):
        span = (fb.recv_ns[idx[-1]] - silence.start_ns) * 1e-9
        return _fail('watchdog_fault', 'ms', f'no drive_fault in the {_ms(span)} after the last '
                     'command (no watchdog?)')
    i = int(faulted[0])
    cycles = int(fb.seq[i] - fb.seq[idx[0]]) + 1
    latency = cycles * _median_period_s(fb)
    wall = (fb.recv_ns[i] - silence.start_ns) * 1e-9
    reason = fb.fault_reason[i]
    ok = latency <= bar and bool(reason)
    return _result('watchdog_fault', ok, latency * 1e3, 'ms',
                   f'drive_fault {cycles} drive cycles ({_ms(latency)}; {_ms(wall)} by reception) '
                   f'after the last command, reason {reason!r}'
                   + ('' if reason else ' (EMPTY: a fault must say why)')
                   + ('' if latency <= bar else f' (later than {_ms(bar)})'))


def rule_watchdog_stop(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that when commands stop, the axis brakes to rest within the timeout + allowance."""
    w = _watch(rec)
    if isinstance(w, str):
        return _fail('watchdog_stop', 'ms', w)
    _, silence, idx = w
    fb = rec.feedback
    p = fb.position_mm[idx]
    t = fb.recv_ns[idx]
    tail = t >= t[-1] - int(0.02e9)
    final = float(np.median(p[tail]))
    if np.ptp(p[tail]) > tol.rest_mm:
        since = _ms((t[-1] - silence.start_ns) * 1e-9)
        return _fail('watchdog_stop', 'ms', f'still moving {since} after the last command '
                     f'({np.ptp(p[tail]) * 1e3:.3g} µm in its last 20 ms, '
                     f'{p[-1] - p[0]:+.3g} mm since): no stop')
    away = np.flatnonzero(np.abs(p - final) > tol.rest_mm)
    k = int(away[-1]) + 1 if len(away) else 0   # first sample of the final rest
    k = min(k, len(idx) - 1)
    cycles = int(fb.seq[idx[k]] - fb.seq[idx[0]]) + 1
    latency = cycles * _median_period_s(fb)
    bar = tol.watchdog_timeout_s + tol.stop_allowance_s
    ok = latency <= bar
    return _result('watchdog_stop', ok, latency * 1e3, 'ms',
                   f'settled within ±{tol.rest_mm * 1e3:g} µm of its rest position {cycles} '
                   f'drive cycles ({_ms(latency)}) after the last command, '
                   f'{(final - p[0]) * 1e3:+.3g} µm travelled after it'
                   + ('' if ok else f' (later than {_ms(bar)})'))


def rule_motion_bag(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check that the bag of the motion tests is written, complete, with its excitation."""
    b = rec.bag
    if b is None:
        return _fail('motion_bag', 'messages', 'no bag written')
    if not b.readable:
        return _fail('motion_bag', 'messages', f'{b.path}: not readable: {b.error}')
    missing = [f'{t} {b.counts.get(t, 0)} of {n}' for t, n in b.expected.items()
               if b.counts.get(t, 0) != n]
    problems = []
    if missing:
        problems.append('messages missing: ' + ', '.join(missing))
    if b.dropped:
        problems.append(f'{b.dropped} dropped by the writer')
    for t in ('/' + COMMAND_TOPIC, '/' + FEEDBACK_TOPIC, '/' + GAP_TOPIC):
        if not b.counts.get(t):
            problems.append(f'no {t}')
    if rec.plan.excitation is not None and rec.segment(EXCITATION) is None:
        problems.append('no excitation segment: ' + rec.why_missing(EXCITATION))
    total = sum(b.counts.values())
    return _result('motion_bag', not problems, total, 'messages',
                   f'{b.path}: {total} messages ({b.counts.get("/" + COMMAND_TOPIC, 0)} commands)'
                   if not problems else '; '.join(problems))


def rule_one_commander(rec: Recording, tol: Tolerances) -> RuleResult:
    """Check the drive executes one commander: a second one is refused, faults, until reset.

    While the prober commands zero (enabled), a second publisher sends upward commands under
    another commander name. The drive must not move, must fault within
    ``commander_fault_s`` (in its own cycles, from the first sample it latched after the
    first foreign send, as the watchdog rule counts), with a reason naming both commanders;
    the fault must hold while the prober alone commands again (no self-clearing), and clear
    after the reset service is called.
    """
    names = (SECOND_COMMANDER, FAULT_HOLDS, RESET_CALL, AFTER_RESET)
    missing = rec.why_missing(*names)
    if missing:
        return _fail('one_commander', 'ms', missing)
    foreign, holds, _, after = (rec.segment(n) for n in names)
    fb = rec.feedback
    if not len(rec.second_send_ns) or not len(fb):
        return _fail('one_commander', 'ms', 'no second commander sent, or no feedback')
    first = int(rec.second_send_ns[0])
    age_ns = int(max(0.0, float(np.median(fb.recv_ns - fb.stamp_ns))))
    idx = np.flatnonzero(fb.window(first + 1 + age_ns, holds.end_ns))
    if len(idx) < 5:
        return _fail('one_commander', 'ms', f'too few feedback samples after the second '
                     f'commander ({len(idx)})')
    problems = []
    p = fb.position_mm[np.flatnonzero(fb.window(foreign.start_ns, holds.end_ns))]
    moved = float(np.ptp(p)) if len(p) else 0.0
    if moved > tol.rest_mm:
        problems.append(f"the axis moved {moved * 1e3:.3g} µm on the second commander's "
                        'upward commands (executed)')
    faulted = idx[fb.drive_fault[idx]]
    latency = math.nan
    if not len(faulted):
        problems.append("no drive_fault after the second commander's commands")
    else:
        i = int(faulted[0])
        cycles = int(fb.seq[i] - fb.seq[idx[0]]) + 1
        latency = cycles * _median_period_s(fb)
        reason = fb.fault_reason[i]
        if latency > tol.commander_fault_s:
            problems.append(f'drive_fault {cycles} drive cycles ({_ms(latency)}) after the '
                            f'first foreign command (later than {_ms(tol.commander_fault_s)})')
        absent = [n for n in (rec.commander, rec.second_commander) if n not in reason]
        if absent:
            problems.append(f'the fault reason {reason!r} does not name '
                            + ' and '.join(repr(n) for n in absent))
        held = np.flatnonzero(fb.window(max(holds.start_ns + age_ns, int(fb.recv_ns[i]) + 1),
                                        holds.end_ns))
        cleared = held[~fb.drive_fault[held]]
        if len(cleared):
            since = _ms((fb.recv_ns[cleared[0]] - first) * 1e-9)
            problems.append(f'the fault cleared by itself {since} after the second commander '
                            'while only the prober commanded (it must hold until the reset)')
    if not rec.reset_answer.startswith('accepted'):
        problems.append(f'the reset service {RESET_SERVICE}: {rec.reset_answer or "not called"}')
    else:
        tail = np.flatnonzero(fb.window(after.end_ns - int(0.05e9), after.end_ns))
        if not len(tail) or fb.drive_fault[tail].any():
            problems.append('still faulted 50 ms before the end of the '
                            f'{_ms((after.end_ns - after.start_ns) * 1e-9)} after the reset')
    if problems:
        return RuleResult('one_commander', False, latency * 1e3 if math.isfinite(latency)
                          else None, 'ms', ' '.join('; '.join(problems).split()))
    return _result('one_commander', True, latency * 1e3, 'ms',
                   f'second commander {rec.second_commander!r} refused: drive_fault after '
                   f'{_ms(latency)}, no motion ({moved * 1e3:.3g} µm), held until the reset, '
                   'ready after it')


@dataclass(frozen=True)
class Rule:
    """One rule: name, what it checks, its tolerance (text from the tolerances), why."""

    name: str
    check: Callable[[Recording, Tolerances], RuleResult]
    what: str
    tolerance: Callable[[Tolerances, Plan], str]
    why: str


RULES: tuple[Rule, ...] = (
    Rule('topics_types', rule_topics_types,
         'the driver publishes axis/capacitive_height and axis/feedback and subscribes '
         'axis/velocity_command, with the contract types; one publisher each; no other node '
         'publishes commands',
         lambda t, p: 'exact',
         'the controller subscribes by name and type; two publishers interleave two seq streams'),
    Rule('qos_publishers', rule_qos_publishers,
         "the sample publishers' QoS: BEST_EFFORT, VOLATILE (the contract's), matching the "
         "controller's BEST_EFFORT keep-last-1 reader",
         lambda t, p: 'exact',
         'a control loop wants the freshest sample; reliable writers at 2 kHz cost the protocol '
         'traffic that made writers overflow (docs/interfaces.md)'),
    Rule('qos_command_input', rule_qos_command_input,
         "the driver's command subscription matches the controller's BEST_EFFORT, VOLATILE "
         'writer (a RELIABLE or TRANSIENT_LOCAL reader does not)',
         lambda t, p: 'exact',
         'an unmatched subscription never receives a command: the drive would only ever see '
         'its watchdog'),
    Rule('rate', rule_rate,
         'samples written per second on each topic (DDS writer sequence over the reception '
         'span)',
         lambda t, p: f'{t.rate_hz:g} Hz ± {t.rate_rel * 100:g} %',
         'the controller ticks at 2 kHz on the freshest sample'),
    Rule('jitter', rule_jitter,
         'p99 of the arrival period of each topic (as the controller receives it)',
         lambda t, p: f'≤ {t.period_p99_s * 1e3:g} ms',
         'a late sample is a tick on the encoder prediction; 10 ms is stale (follow.'
         'stale_timeout_s)'),
    Rule('seq_increments', rule_seq_increments,
         'seq grows by exactly one per sample written (compared with the DDS writer sequence, '
         'so transport loss is not counted against the driver)',
         lambda t, p: '0 wrong steps',
         'loss and latency are measured from seq (controller, recorder, report)'),
    Rule('stamps_monotonic', rule_stamps_monotonic,
         'header stamps strictly increase',
         lambda t, p: '0 non-increasing',
         'stamps order the samples in bags and replay'),
    Rule('stamps_not_future', rule_stamps_not_future,
         'no header stamp later than its own reception',
         lambda t, p: f'≤ {t.future_s * 1e3:g} ms',
         'the controller invalidates a sample stamped in the future (docs/safety.md); the '
         'allowance is the clock offset of a driver on another host'),
    Rule('stamp_age', rule_stamp_age,
         'reception minus stamp (latch to arrival): median, and the share older than the '
         "controller's stamp tolerance",
         lambda t, p: f'median ≤ {t.age_median_s * 1e3:g} ms, ≤ {t.age_late_share * 100:g} % '
                      f'older than {t.age_limit_s * 1e3:g} ms',
         "latency adds to the loop's dead time (delay margin 12 ms); the controller rejects "
         'samples older than 10 ms (stamp_tolerance_s)'),
    Rule('drive_ready', rule_drive_ready,
         'before any command: drive_enabled, no drive_fault, valid readings, gap above the '
         'minimum',
         lambda t, p: f'gap ≥ {p.min_gap_mm:g} mm',
         'the motion tests start only at a safe height on a ready drive'),
    Rule('enable_false_holds', rule_enable_false_holds,
         'an upward velocity with enable=false: the encoder does not move',
         lambda t, p: f'travel ≤ {t.enable_travel_mm:g} mm',
         'VelocityCommand.enable=false means hold zero whatever velocity_mm_s says'),
    Rule('motion_direction', rule_motion_direction,
         'commanded up then down: the encoder moves up then down',
         lambda t, p: 'same sign',
         'Z positive up, command positive up: a wrong sign drives the nozzle into the sheet'),
    Rule('motion_speed', rule_motion_speed,
         '|encoder speed| over |commanded speed| in the steady part of each half',
         lambda t, p: f'1 ± {t.speed_rel:g}',
         'the controller assumes b0 = 1 (mm/s per mm/s); identification refines it'),
    Rule('velocity_feedback', rule_velocity_feedback,
         'AxisFeedback.velocity_mm_s against the slope of position_mm',
         lambda t, p: f'1 ± {t.velocity_rel:g}',
         'the velocity field must be mm/s, positive up'),
    Rule('gap_tracks_encoder', rule_gap_tracks_encoder,
         'gap reading against encoder position over the up/down test (flat resting sheet)',
         lambda t, p: f'slope 1 ± {t.gap_slope_rel:g}',
         'gap in mm, growing as the axis rises; µm or a wrong table show up here'),
    Rule('watchdog_fault', rule_watchdog_fault,
         'commands stop: drive_fault with a fault_reason, latency in drive cycles',
         lambda t, p: f'≤ {(t.watchdog_timeout_s + t.watchdog_allowance_s) * 1e3:g} ms '
                      f'({t.watchdog_timeout_s * 1e3:g} ms timeout + '
                      f'{t.watchdog_allowance_s * 1e3:g} ms)',
         'a silent controller must not leave the axis moving (docs/safety.md: 5 ms)'),
    Rule('watchdog_stop', rule_watchdog_stop,
         'commands stop: the axis comes to rest (within rest_mm)',
         lambda t, p: f'≤ {(t.watchdog_timeout_s + t.stop_allowance_s) * 1e3:g} ms, rest '
                      f'within {t.rest_mm * 1e3:g} µm',
         'quick stop at the maximum deceleration after the watchdog'),
    Rule('one_commander', rule_one_commander,
         "a second commander's (upward) commands while the prober commands: not executed, "
         'drive_fault naming both, held until the reset service, ready after it',
         lambda t, p: f'fault ≤ {t.commander_fault_s * 1e3:g} ms, travel ≤ '
                      f'{t.rest_mm * 1e3:g} µm',
         'a second publisher at 1 kHz drove the nozzle 0.49 mm into the sheet; the drive is '
         'where a command is executed, so it is where one commander is enforced'),
    Rule('motion_bag', rule_motion_bag,
         'the bag of everything seen and sent, read back: every message there, the excitation '
         'segment included',
         lambda t, p: 'all messages',
         'the bag is the input of ladrc identify'),
)
RULE_NAMES = tuple(r.name for r in RULES)


def evaluate(rec: Recording, tol: Tolerances | None = None) -> ConformanceResult:
    """Judge a recording against every rule; a rule that raises is a failure with the error."""
    tol = tol or Tolerances()
    out = []
    for rule in RULES:
        try:
            r = rule.check(rec, tol)
        except Exception as exc:  # noqa: BLE001 - one broken figure must not hide the rest
            r = _fail(rule.name, '', f'could not be evaluated: {type(exc).__name__}: {exc}')
        r.tolerance = rule.tolerance(tol, rec.plan)
        out.append(r)
    return ConformanceResult(out, rec.aborted, rec.not_run, list(rec.notes))


# ---- the sim node as a drive ------------------------------------------------------------------
def sim_scenario_yaml(start_gap_mm: float = 5.0, duration_s: float = 120.0) -> str:
    """Return the scenario under which the sim node is a plain drive (``ladrc conform --sim``).

    A flat resting sheet (no profile), no follow commands (the sim node then waits for no
    controller and only executes ``axis/velocity_command``), the nozzle parked
    ``start_gap_mm`` above the sheet, the showcase's sensor (5 µm noise, 1 µm steps, 0.2 ms
    lag) and the default axis (T1 = 8 ms, b0 = 1, 5 ms watchdog in the node). The run lasts
    ``duration_s`` unless the prober stops the node first (it does, by PID).
    """
    return (
        'name: conform_drive\n'
        'description: >-\n'
        '  The sim node as a plain drive for ladrc conform --sim: flat resting sheet, no follow\n'
        f'  commands, nozzle parked {start_gap_mm:g} mm above the sheet.\n'
        f'duration_s: {duration_s:g}\n'
        'seed: 7\n'
        f'initial_gap_mm: {start_gap_mm:g}\n'
        'sensor: {noise_std_mm: 0.005, quant_mm: 0.001, lag_s: 0.0002}\n'
        'timeline: []\n')


# ---- the report -----------------------------------------------------------------------------
def _fmt(v: float | None) -> str:
    if v is None or not math.isfinite(v):
        return '—'
    return f'{v:.4g}'


def markdown(result: ConformanceResult, title: str, lines: list[str] | None = None,
             segments: list[Segment] | None = None) -> str:
    """Return the Markdown report of a run: the verdict, the rule table, the segments."""
    n = len(result.results)
    out = [f'# Driver conformance: {title}', '']
    out += [f'**{"PASS" if result.passed else "FAIL"}**: {len(result.rules_passed)} of {n} rules '
            'passed' + ('' if result.passed else f'; failed: {", ".join(result.rules_failed)}'),
            '']
    out += [f'- {line}' for line in (lines or [])]
    if result.aborted:
        out.append(f'- motion tests ABORTED: {result.aborted}')
    if result.not_run:
        out.append(f'- motion tests NOT RUN: {result.not_run}')
    out += [f'- note: {n_}' for n_ in result.notes]
    out += ['', '| rule | result | figure | tolerance | reason |',
            '| --- | --- | --- | --- | --- |']
    for r in result.results:
        fig = _fmt(r.figure) + (f' {r.unit}' if r.figure is not None else '')
        reason = r.reason.replace('|', '\\|')
        out.append(f'| `{r.name}` | {"pass" if r.passed else "**FAIL**"} | {fig} | '
                   f'{r.tolerance} | {reason} |')
    if segments:
        t0 = segments[0].start_ns
        out += ['', '## The run', '', '| segment | from [s] | to [s] | command [mm/s] | enable |',
                '| --- | --- | --- | --- | --- |']
        for s in segments:
            cmd = f'{s.velocity_mm_s:+g}' if s.commanded else 'none'
            out.append(f'| {s.name} | {(s.start_ns - t0) * 1e-9:.3f} | '
                       f'{(s.end_ns - t0) * 1e-9:.3f} | {cmd} | '
                       f'{str(s.enable).lower() if s.commanded else "—"} |')
    out += ['', 'Rules, tolerances and why: docs/conformance.md.', '']
    return '\n'.join(out)
