"""Where a bag comes from: machine, wall-clock start, parameter set, software version.

The writers put four keys into the bag's ``custom_data`` (``metadata.yaml``, as ``ros2 bag
record`` keeps custom data): ``ladrc.machine_id`` (the follow node's ``hardware_id``, the
recorder's ``machine_id`` parameter), ``ladrc.start_utc`` (ISO 8601, UTC, when the writer
opened), ``ladrc.param_hash`` (:func:`param_hash` of the first ``run/parameters`` text) and
``ladrc.version`` (the ``ladrc_bags`` version that wrote it). :func:`read_provenance` reads
them back; for a bag written before they existed it falls back, per key, and says which keys
came from a fallback (docs/fleet.md):

* machine id: ``unknown``;
* start: the bag's starting time when it is a wall-clock time (a recorder bag: receive times),
  else none (a headless bag of the past: sim time from 0);
* parameter hash: :func:`param_hash` of the bag's first ``run/parameters`` text, else empty;
* version: empty.
"""

from __future__ import annotations

from dataclasses import dataclass
import datetime as dt
import hashlib
from typing import Any

MACHINE_KEY = 'ladrc.machine_id'
START_KEY = 'ladrc.start_utc'
PARAMS_KEY = 'ladrc.param_hash'
VERSION_KEY = 'ladrc.version'
UNKNOWN_MACHINE = 'unknown'
WALL_CLOCK_MIN_NS = 946_684_800 * 10**9
"""2000-01-01: a bag time before it is sim time (a headless run starts at 0), not a date."""


def param_hash(text: str) -> str:
    """Return the parameter set's hash: the first 12 hex digits of SHA-256 of its YAML text."""
    return hashlib.sha256(text.encode('utf-8')).hexdigest()[:12] if text else ''


def software_version() -> str:
    """Return the ``ladrc_bags`` version (installed package metadata, else the source's)."""
    from importlib import metadata

    try:
        return metadata.version('ladrc_bags')
    except metadata.PackageNotFoundError:
        from . import __version__

        return __version__


def utc_iso(t: dt.datetime | None = None) -> str:
    """Return ``t`` (default: now) as ISO 8601 UTC with seconds, ``YYYY-MM-DDThh:mm:ssZ``."""
    t = t or dt.datetime.now(dt.timezone.utc)
    return t.astimezone(dt.timezone.utc).strftime('%Y-%m-%dT%H:%M:%SZ')


def parse_utc(text: str) -> dt.datetime | None:
    """Return the datetime of an ISO 8601 text (naive: UTC), None when it is not one."""
    try:
        t = dt.datetime.fromisoformat(text.replace('Z', '+00:00'))
    except (TypeError, ValueError):
        return None
    return t if t.tzinfo else t.replace(tzinfo=dt.timezone.utc)


def provenance_data(machine_id: str, start_utc: str | None = None, params_text: str = ''
                    ) -> dict[str, str]:
    """Return the ``custom_data`` entries of a new bag (the parameter hash when known)."""
    data = {MACHINE_KEY: machine_id or UNKNOWN_MACHINE, START_KEY: start_utc or utc_iso(),
            VERSION_KEY: software_version()}
    if params_text:
        data[PARAMS_KEY] = param_hash(params_text)
    return data


@dataclass(frozen=True)
class Provenance:
    """A bag's origin; ``fallback``: the keys not in the bag, filled by the fallback rules."""

    machine_id: str
    start_utc: str            # ISO 8601 UTC; '' when unknown
    param_hash: str
    version: str
    fallback: tuple[str, ...] = ()

    @property
    def day(self) -> str:
        """Return the start's date (``YYYY-MM-DD``), ``unknown`` without a start."""
        return self.start_utc[:10] if self.start_utc else 'unknown'


def read_provenance(bag: Any) -> Provenance:
    """Return the provenance of an open :class:`~.reader.Bag` (fallbacks: module docstring)."""
    custom = bag.custom_data
    fallback = []
    machine = custom.get(MACHINE_KEY, '')
    if not machine:
        machine = UNKNOWN_MACHINE
        fallback.append('machine_id')
    start = custom.get(START_KEY, '')
    if not parse_utc(start):
        fallback.append('start_utc')
        start_ns = int(getattr(bag.reader, 'start_time', 0) or 0)
        start = (utc_iso(dt.datetime.fromtimestamp(start_ns / 1e9, dt.timezone.utc))
                 if start_ns >= WALL_CLOCK_MIN_NS else '')
    phash = custom.get(PARAMS_KEY, '')
    if not phash:
        fallback.append('param_hash')
        from .reader import read_first_text

        phash = param_hash(read_first_text(bag, 'run/parameters') or '')
    version = custom.get(VERSION_KEY, '')
    if not version:
        fallback.append('version')
    return Provenance(machine, start, phash, version, tuple(fallback))
