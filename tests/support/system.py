"""System packages a test needs (LinuxCNC, Chromium): run it, or say why it cannot run.

``scripts/system-packages`` (called by the set-up) installs them as root and writes
``.system-packages``: one line per integration, ``NAME ok`` or ``NAME missing REASON``. A test
that needs one calls :func:`require` (or uses :func:`needs` as a decorator): where it is
missing the test is skipped with the set-up's reason, which names the command to run, and
``scripts/run-tests`` lists every such test at the end of ``make test`` (never silently).
"""

from __future__ import annotations

from pathlib import Path
import shutil

import pytest

ROOT = Path(__file__).resolve().parents[2]
STATE = ROOT / '.system-packages'
PROGRAMS = {'linuxcnc': ('linuxcnc', 'halcmd'), 'chromium': ('chromium', 'chromedriver')}
SKIP_PREFIX = 'could not run, needs '  # run-tests looks for this in pytest's skip lines


def missing(name: str) -> str:
    """Return why ``name`` is missing ('' when it is installed)."""
    if all(shutil.which(p) for p in PROGRAMS[name]):
        return ''
    try:
        for line in STATE.read_text(encoding='utf-8').splitlines():
            key, _, rest = line.partition(' ')
            state, _, why = rest.partition(' ')
            if key == name and state == 'missing' and why:
                return why
    except OSError:
        pass
    return f'{name} is not installed ({", ".join(PROGRAMS[name])} not on PATH)'


def require(name: str) -> None:
    """Skip the calling test, naming what to install, when ``name`` is missing."""
    why = missing(name)
    if why:
        pytest.skip(f'{SKIP_PREFIX}{name}: {why}')


def needs(name: str):
    """Return the decorator form of :func:`require` (evaluated at collection)."""
    why = missing(name)
    return pytest.mark.skipif(bool(why), reason=f'{SKIP_PREFIX}{name}: {why}')
