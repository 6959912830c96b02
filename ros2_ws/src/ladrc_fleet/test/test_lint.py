"""colcon test: lint this package with the project's rules (ruff, pyproject.toml)."""

from pathlib import Path
import shutil
import subprocess

import pytest

PKG = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(shutil.which('ruff') is None, reason='ruff not installed')
def test_ruff():
    r = subprocess.run(['ruff', 'check', str(PKG)], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
