"""The parameter set a replay runs: the bag's own, or a what-if set from a file and overrides.

``--set key=value`` overrides (values as YAML) and ``--params FILE`` on top of the bag's
recorded set; the delta from the recorded set is reported with the result.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Mapping

from ladrc_follow import ControllerParams, ParameterError, dotted, params_from_dict, params_to_dict
import yaml

from .recording import Recording, ReplayError


# ---- what-if parameters -----------------------------------------------------------------------
def parse_set(items: Iterable[str]) -> dict[str, Any]:
    """Parse ``key=value`` overrides (value as YAML: ``law.kp=12``, ``follow.controller=pid``)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition('=')
        key = key.strip()
        if not sep or not key:
            raise ReplayError(f'--set {item!r}: use key=value, e.g. law.kp=12.5')
        try:
            out[key] = yaml.safe_load(text)
        except yaml.YAMLError:
            raise ReplayError(f'--set {item!r}: the value is not valid YAML') from None
    return out


def _with(base: ControllerParams, overrides: Mapping[str, Any], what: str) -> ControllerParams:
    flat = dotted(params_to_dict(base))
    unknown = sorted(k for k in overrides if k not in flat)
    if unknown:
        raise ReplayError(f'{what}: unknown parameter {", ".join(unknown)} (names as in '
                          '`ros2 param list`, e.g. law.kp, eso.w0_rad_s)')
    flat.update(overrides)
    try:
        return params_from_dict(flat)  # offline, open loop: nothing goes live
    except ParameterError as exc:
        raise ReplayError(f'{what}: {"; ".join(exc.reasons)}') from None


def whatif_params(rec: Recording, params_file: str | Path | None = None,
                  overrides: Mapping[str, Any] | None = None) -> ControllerParams:
    """Return the what-if set: ``params_file`` (else the bag's set) with ``overrides`` on top.

    :class:`ReplayError` for an unreadable file, an unknown key or an invalid set; the period
    ``h_s`` cannot change (the recorded ticks are ``h_s`` apart).
    """
    base = rec.params
    if params_file is not None:
        p = Path(params_file)
        try:
            data = yaml.safe_load(p.read_text(encoding='utf-8'))
        except OSError as exc:
            raise ReplayError(f'--params {p}: cannot read it ({exc.strerror or exc})') from None
        except yaml.YAMLError:
            raise ReplayError(f'--params {p}: not valid YAML') from None
        try:
            base = params_from_dict(data)
        except ParameterError as exc:
            raise ReplayError(f'--params {p}: {"; ".join(exc.reasons)}') from None
    out = _with(base, dict(overrides or {}), '--set') if overrides else base
    if out.h_s != rec.h_s:
        raise ReplayError(f"h_s {out.h_s:g} s differs from the recording's {rec.h_s:g} s: a "
                          'replay runs at the recorded ticks')
    return out


def _delta(old: ControllerParams, new: ControllerParams) -> dict[str, Any]:
    a, b = dotted(params_to_dict(old)), dotted(params_to_dict(new))
    return {k: v for k, v in b.items() if a.get(k) != v}
