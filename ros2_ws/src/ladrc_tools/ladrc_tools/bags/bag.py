"""rosbag2 bags of a run, the tools' front: a crash-safe writer and a reader into numpy columns.

The package is split by concern, as ``rosbags`` splits its ``rosbag2`` package:
:mod:`.writer` (:class:`BagWriter`), :mod:`.rows` (many fixed-layout messages at once),
:mod:`.run_bag` (a headless run as a bag), :mod:`.reader` (:func:`open_bag`, :class:`Bag`),
:mod:`.recovery` (what a killed writer left), :mod:`.errors`. This module re-exports their
public names, so ``from ladrc_tools.bags.bag import open_bag`` keeps working.
"""

from __future__ import annotations

from .errors import BagError
from .reader import Bag, count_lost, open_bag, read_first_text, read_text_topic, seq_of
from .rows import RowPacker, stamp_parts
from .run_bag import write_run_bag
from .writer import BAG_VERSION, STORAGES, BagWriter, fq, rosbags_qos, storage_of, string_msg

__all__ = ['BAG_VERSION', 'STORAGES', 'Bag', 'BagError', 'BagWriter', 'RowPacker', 'count_lost',
           'fq', 'open_bag', 'read_first_text', 'read_text_topic', 'rosbags_qos', 'seq_of',
           'stamp_parts', 'storage_of', 'string_msg', 'write_run_bag']
