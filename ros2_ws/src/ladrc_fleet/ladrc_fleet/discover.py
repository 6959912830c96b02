"""Which bags a fleet run reads: bag folders under the given trees and globs.

A bag folder is one with a ``metadata.yaml``. Still being written (listed, skipped): a headless
or generated bag's temporary folder (``.NAME.partial``: renamed into place when complete), and
a recorder's bag without its ``recording.json`` (written when the recorder stops) whose files
changed within the last ``settle_s`` seconds. A recorder's bag without ``recording.json`` and
quiet for longer is a recording whose writer was killed: it is read (the bag reader's scan
recovers what it wrote).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import glob
from pathlib import Path
import time

SETTLE_S = 60.0
"""A recorder's bag without recording.json whose files changed this recently is being written."""


@dataclass
class Found:
    """The bag folders found, those skipped as still being written, and paths not found."""

    bags: list[Path] = field(default_factory=list)
    writing: list[Path] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)


def _being_written(bag: Path, now: float, settle_s: float) -> bool:
    if bag.name.startswith('.') and bag.name.endswith('.partial'):
        return True
    if (bag / 'recording.json').is_file():
        return False
    try:
        meta = (bag / 'metadata.yaml').read_text(encoding='utf-8', errors='replace')
    except OSError:
        return False
    if 'ladrc.source: recorder' not in meta:
        return False
    newest = max((f.stat().st_mtime for f in bag.iterdir() if f.is_file()), default=0.0)
    return now - newest < settle_s


def find_bags(paths: list[str], settle_s: float = SETTLE_S) -> Found:
    """Return the bag folders under ``paths`` (folders searched recursively, or globs)."""
    found = Found()
    seen: set[Path] = set()
    now = time.time()
    for arg in paths:
        roots = [Path(p) for p in sorted(glob.glob(arg, recursive=True))] or (
            [Path(arg)] if Path(arg).exists() else [])
        if not roots:
            found.missing.append(arg)
            continue
        for root in roots:
            metas = [root / 'metadata.yaml'] if (root / 'metadata.yaml').is_file() else (
                sorted(root.rglob('metadata.yaml')) if root.is_dir() else [])
            for meta in metas:
                bag = meta.parent.resolve()
                if bag in seen:
                    continue
                seen.add(bag)
                (found.writing if _being_written(bag, now, settle_s) else found.bags).append(bag)
    return found
