"""The verdict of a conformance run: a result per rule, the run's result, its report.md."""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any

from .conformance_recording import Segment


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


# ---- helpers --------------------------------------------------------------------------------
def fmt_ms(seconds: float) -> str:
    """Return seconds as milliseconds, three digits."""
    return f'{seconds * 1e3:.3g} ms'


def rule_result(name: str, ok: bool, figure: float | None, unit: str, reason: str) -> RuleResult:
    """Return a rule's result with its figure and its reason on one line."""
    return RuleResult(name, bool(ok), None if figure is None else float(figure), unit,
                      ' '.join(reason.split()))


def rule_failure(name: str, unit: str, reason: str) -> RuleResult:
    """Return a failed rule without a figure."""
    return rule_result(name, False, None, unit, reason)
