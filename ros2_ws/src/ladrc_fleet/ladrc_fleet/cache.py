"""The fleet's cache: a bag's row kept under its content key (bag_task.content_key).

One JSON file per key in ``<out>/cache/``: a re-run over a tree with new bags computes only
the bags whose content it has not seen, wherever they lie now. A row computed by another
version of the tools is computed again (``tools_version`` in the file).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from ladrc_bags.provenance import software_version


class RowCache:
    """Rows by content key, in a folder (created on first write)."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self.version = software_version()

    def get(self, key: str) -> dict[str, Any] | None:
        """Return the cached row of ``key`` (None: not cached, unreadable or another version)."""
        try:
            data = json.loads((self.folder / f'{key}.json').read_text(encoding='utf-8'))
        except (OSError, ValueError):
            return None
        if data.get('tools_version') != self.version or not isinstance(data.get('row'), dict):
            return None
        return data['row']

    def put(self, key: str, row: dict[str, Any]) -> None:
        """Keep ``row`` under ``key`` (written whole or not at all)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        tmp = self.folder / f'.{key}.json.tmp'
        tmp.write_text(json.dumps({'tools_version': self.version, 'row': row}),
                       encoding='utf-8')
        os.replace(tmp, self.folder / f'{key}.json')
