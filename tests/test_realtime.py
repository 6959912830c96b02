"""A loop process's real-time set-up (ladrc_contract/realtime.py) turns numpy's huge pages off.

numpy advises transparent huge pages for arrays of 4 MB or more; the kernel then collapses and
compacts memory under the process's memory map lock, which stalled the sim node's loop for
7-30 ms in free-running jobs (realtime.no_huge_pages). Run in a process of its own (the setting
is the process's), as a node's main runs it: numpy imported first, then apply_realtime.
"""

from __future__ import annotations

import json
from pathlib import Path
import subprocess
import sys

SRC = Path(__file__).resolve().parents[1] / 'ros2_ws' / 'src'

PROBE = """
import json, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from ladrc_contract.realtime import apply_realtime
core = getattr(np, '_core', None) or np.core
switch = core.multiarray._set_madvise_hugepage
before = switch(True)  # numpy's default here (and turned on, whatever it was)
applied, warnings = apply_realtime(0, [], False)
after = switch(True)  # returns the setting apply_realtime left
print(json.dumps({'before': bool(before), 'after': bool(after), 'applied': applied,
                  'warnings': warnings}))
"""


def test_apply_realtime_turns_numpys_huge_pages_off() -> None:
    out = subprocess.run([sys.executable, '-c', PROBE, str(SRC / 'ladrc_contract')],
                         capture_output=True, text=True, check=True, timeout=120)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result['after'] is False, result
    assert 'no huge pages for arrays' in result['applied'], result
    assert not any('huge' in w for w in result['warnings']), result
