"""Field-by-field comparison of two bags, message by message (no rclpy).

Used to show that a live run in lock step equals the headless runner bit for bit: every field
of every message of the compared topics, in order, except the fields a caller names (those that
measure wall time). NaN equals NaN; anything else must be identical (floats compared as bits).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ladrc_bags import open_bag
import numpy as np


@dataclass
class TopicDiff:
    """What differs on one topic: message counts, fields missing, fields with other values."""

    topic: str
    count_a: int
    count_b: int
    compared: int
    missing: list[str] = field(default_factory=list)
    differing: dict[str, tuple[int, int, object, object]] = field(default_factory=dict)

    @property
    def equal(self) -> bool:
        return not self.missing and not self.differing and self.count_a == self.count_b


def _same(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    if x.dtype == object or y.dtype == object:
        return np.array([str(p) == str(q) for p, q in zip(x, y, strict=True)], dtype=bool)
    if x.dtype.kind == 'f' and y.dtype.kind == 'f':
        return (x.view(np.int64) == y.view(np.int64)) | (np.isnan(x) & np.isnan(y))
    return x == y


def diff_topic(a, b, topic: str, ignore: set[str], limit: int | None = None) -> TopicDiff:
    """Compare ``topic`` of two open bags (the first ``limit`` messages, default all of a)."""
    ca = {k: v for k, v in a.columns(topic).items() if k not in ignore}
    cb = {k: v for k, v in b.columns(topic).items() if k not in ignore}
    na = len(next(iter(ca.values()))) if ca else 0
    nb = len(next(iter(cb.values()))) if cb else 0
    n = min(na, nb) if limit is None else min(limit, na, nb)
    out = TopicDiff(topic, na, nb, n)
    for k in sorted(set(ca) | set(cb)):
        if k not in ca or k not in cb:
            out.missing.append(k)
            continue
        eq = _same(np.asarray(ca[k][:n]), np.asarray(cb[k][:n]))
        if not eq.all():
            i = int(np.argmin(eq))
            out.differing[k] = (int((~eq).sum()), i, ca[k][i], cb[k][i])
    return out


def diff_bags(path_a, path_b, topics: list[str], ignore: set[str],
              limit: dict[str, int] | None = None) -> list[TopicDiff]:
    """Compare ``topics`` of two bags; ``limit``: per topic, compare only that many messages."""
    with open_bag(path_a) as a, open_bag(path_b) as b:
        return [diff_topic(a, b, t, ignore, (limit or {}).get(t)) for t in topics]
