"""Output folders of the tools: built under a temporary name, renamed when complete.

A report, an export, a what-if or an analysis that fails half-way (bad input, a full disk,
Ctrl-C) leaves nothing behind: the files are written into ``.<name>.partial`` beside the
output and the folder is renamed to ``<name>`` only once every file is in it.
"""

from __future__ import annotations

from contextlib import contextmanager
import os
from pathlib import Path
import shutil
from typing import Iterator


@contextmanager
def building(out: Path) -> Iterator[Path]:
    """Yield the temporary folder to write into; rename it to ``out`` on success."""
    tmp = out.with_name(f'.{out.name}.partial')
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        tmp.mkdir(parents=True)
        yield tmp
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
