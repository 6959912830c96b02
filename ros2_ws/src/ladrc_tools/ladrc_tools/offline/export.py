"""CSV export of a bag: one CSV per topic, header row of flattened field names.

Columns are ``timestamp_ns`` (bag time), the message's fields flattened with dots
(``header.stamp.sec``) and ``stamp_s`` where the message has a header. Sequences (the
diagnostics' status list) are written as their text. The output folder is written under a
temporary name and renamed when complete.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Callable, Iterable

from ladrc_bags import BagError, open_bag
import numpy as np

from .outdir import building

EXPORT_CHUNK = 8192
"""Messages formatted at a time."""


def topic_filename(topic: str) -> str:
    """``axis/capacitive_height`` -> ``axis__capacitive_height.csv`` (leading / dropped)."""
    return topic.strip('/').replace('/', '__') + '.csv'


def export_csv(bag_path: str | Path, out_dir: str | Path | None = None,
               progress: Callable[[str], Callable[[int, int], None]] | None = None
               ) -> list[Path]:
    """Write one CSV per topic of the bag into ``out_dir`` (default ``<bag>_csv``)."""
    bag_path = Path(bag_path)
    out = Path(out_dir) if out_dir else bag_path.with_name(bag_path.name + '_csv')
    if out.exists():
        raise BagError(f'{out} exists already: choose another output folder (-o)')
    with open_bag(bag_path) as bag, building(out) as tmp:
        if not bag.topics:
            raise BagError(f'{bag_path}: no message could be read (a truncated or empty '
                           'storage file)')
        names = []
        for topic in sorted(bag.topics):
            name = topic_filename(topic)
            # one chunk of columns at a time: memory stays that of a chunk, at any length
            # (a chunk's rows become Python strings: EXPORT_CHUNK keeps them few)
            _write(tmp / name, bag.iter_columns(
                topic, progress=progress(topic) if progress else None, chunk=EXPORT_CHUNK))
            names.append(name)
    return [out / n for n in names]


def _write(path: Path, chunks: Iterable[dict[str, np.ndarray]]) -> None:
    with path.open('w', newline='', encoding='utf-8') as f:
        w = csv.writer(f)
        header = False
        for cols in chunks:
            keys = list(cols)
            if not header:
                w.writerow(keys)
                header = True
            columns = []
            for k in keys:
                c = cols[k]
                if c.dtype == bool:
                    c = c.astype(np.int8)  # 0/1: spreadsheets and numpy read it back as numbers
                if c.dtype.kind == 'f':
                    columns.append([repr(float(x)) for x in c])
                else:
                    columns.append(c.tolist())
            w.writerows(zip(*columns, strict=True))
        if not header:
            w.writerow(['timestamp_ns'])
