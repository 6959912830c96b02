"""rosbag2 bags of a run: a crash-safe writer, a reader into numpy columns, and the recorder node.

Split by concern, as ``rosbags`` splits its ``rosbag2`` package: :mod:`.writer`
(:class:`BagWriter`), :mod:`.rows` (many fixed-layout messages at once), :mod:`.run_bag` (a
headless run as a bag), :mod:`.reader` (:func:`open_bag`, :class:`Bag`), :mod:`.recovery` (what
a killed writer left), :mod:`.provenance` (machine, start, parameter hash, version),
:mod:`.typestore`, :mod:`.columns`, :mod:`.mcap_index`, :mod:`.layouts` (PlotJuggler and
Foxglove layouts), :mod:`.errors`. The public names are exported here; none of these modules
imports rclpy. :mod:`.recorder_node` is the ROS side (the ``recorder`` executable).
"""

from __future__ import annotations

from .errors import BagError
from .provenance import (
    MACHINE_KEY,
    PARAMS_KEY,
    START_KEY,
    VERSION_KEY,
    Provenance,
    param_hash,
    provenance_data,
    read_provenance,
    software_version,
)
from .reader import Bag, count_lost, open_bag, read_first_text, read_text_topic, seq_of
from .rows import RowPacker, stamp_parts
from .run_bag import write_run_bag
from .typestore import ladrc_typestore
from .writer import BAG_VERSION, STORAGES, BagWriter, fq, rosbags_qos, storage_of, string_msg

__version__ = '0.1.0'  # as package.xml and setup.py (provenance.software_version)

__all__ = ['BAG_VERSION', 'MACHINE_KEY', 'PARAMS_KEY', 'START_KEY', 'STORAGES', 'VERSION_KEY',
           'Bag', 'BagError', 'BagWriter', 'Provenance', 'RowPacker', 'count_lost', 'fq',
           'ladrc_typestore', 'open_bag', 'param_hash', 'provenance_data', 'read_first_text',
           'read_provenance', 'read_text_topic', 'rosbags_qos', 'seq_of', 'software_version',
           'stamp_parts', 'storage_of', 'string_msg', 'write_run_bag']
