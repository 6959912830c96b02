"""Reading what a killed writer left: MCAP files without their summary, by a scan."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator

import yaml

from .mcap_file import McapScan, is_complete
from .typestore import ladrc_typestore


@dataclass
class _ScanTopic:
    msgtype: str
    msgcount: int


@dataclass
class _ScanConnection:
    topic: str
    msgtype: str


class _ScanReader:
    """The part of rosbags' ``AnyReader`` that :class:`Bag` uses, over scanned MCAP files.

    For a bag whose writer was killed: its last file has no summary, which rosbags cannot
    open. Every file is scanned (:class:`.mcap_file.McapScan`); message types the bag defines
    and the contract's typestore does not know are registered from their definitions.
    """

    def __init__(self, files: list[Path]) -> None:
        from rosbags.typesys import get_types_from_msg

        self.scans = [McapScan(f) for f in files]
        self.typestore = ladrc_typestore()
        self.topics: dict[str, _ScanTopic] = {}
        for scan in self.scans:
            for name, t in scan.topics.items():
                cur = self.topics.get(name)
                self.topics[name] = _ScanTopic(t.msgtype, t.msgcount + (cur.msgcount
                                                                       if cur else 0))
            for msgtype, text in scan.schemas.items():
                if msgtype not in self.typestore.types:
                    try:
                        self.typestore.register(get_types_from_msg(text, msgtype))
                    except Exception:  # a definition rosbags cannot parse: raw bytes only
                        pass
        self.connections = [_ScanConnection(n, t.msgtype) for n, t in self.topics.items()]

    def messages(self, connections: Iterable[_ScanConnection]
                 ) -> Iterator[tuple[_ScanConnection, int, bytes]]:
        conns = {c.topic: c for c in connections}
        for scan in self.scans:
            for topic, ts, data in scan.messages(conns):
                yield conns[topic], ts, data

    def deserialize(self, data: bytes, msgtype: str) -> Any:
        return self.typestore.deserialize_cdr(data, msgtype)

    def close(self) -> None:
        self.scans = []


def _unfinished_mcap(folder: Path) -> list[Path] | None:
    """Return the MCAP files if one has no footer (its writer was killed), else None."""
    try:
        info = yaml.safe_load((folder / 'metadata.yaml').read_text(encoding='utf-8'))
        meta = info['rosbag2_bagfile_information']
        if meta.get('storage_identifier') != 'mcap':
            return None
        files = [folder / str(f) for f in meta.get('relative_file_paths') or []]
    except (OSError, ValueError, yaml.YAMLError, KeyError, TypeError, AttributeError):
        return None  # AnyReader says what is wrong with it (UnicodeDecodeError: a ValueError)
    files = [f for f in files if f.is_file()]
    if files and not all(is_complete(f) for f in files):
        return files
    return None
