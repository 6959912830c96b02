"""Reading a bag into columns: MCAP indexes + column decoding vs message by message (rosbags).

    scripts/in-env python bench/bag_read.py [--bag DIR] [--seconds 600]

Without ``--bag``, a headless run of ``--seconds`` (a sine sheet, the shipped controller) is
written as a bag first. Then every topic, every field, is read into numpy columns three times
in this process: through the MCAP chunk and message indexes with the column decoder
(``Bag.read_topics``, the tools' path: ``indexed``), through rosbags' reader with the column
decoder (``unindexed``: a bag without indexes), and message by message through rosbags'
``deserialize_cdr`` (``per_message``: what the reader did for any message with a nonempty
string before). All three are checked equal, strings included. Then the price of a string:
the 2 kHz command topic (``commander`` names the follow node in every message) decoded as
recorded and re-serialized with an empty ``commander`` (a fixed layout).

Last line: JSON with ``messages``, ``indexed``, ``indexed_s``, ``unindexed_s``,
``per_message_s``, ``indexed_msgs_per_s``, ``per_message_msgs_per_s``, ``speedup``
(per_message / indexed), ``same_columns``, ``command_with_string_s``,
``command_fixed_s`` (decoding the command topic's messages, as recorded and without the
string) and ``command_messages``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import shutil
import sys
import tempfile
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'ros2_ws' / 'src' / 'ladrc_tools'))
sys.path.insert(0, str(ROOT / 'ros2_ws' / 'src' / 'ladrc_bags'))

from ladrc_bags import open_bag  # noqa: E402


def _headless_bag(path: Path, seconds: float) -> None:
    from bag_scale import shift_scenario  # the same shift as the other bag benches
    from ladrc_bags import write_run_bag
    from ladrc_follow.control.follow import FollowController
    from ladrc_follow.control.params import ControllerParams, dump_params
    from ladrc_sim.headless.runner import run
    from ladrc_sim.headless.scenario import scenario_from_dict

    sc = scenario_from_dict(shift_scenario(seconds))
    params = ControllerParams()
    write_run_bag(run(sc, FollowController(params), record_internals=True), path,
                  dump_params(params), 'name: shift\n')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--bag', default=None, help='bag to read (default: write a headless one)')
    ap.add_argument('--seconds', type=float, default=600.0, help='headless bag length [s]')
    a = ap.parse_args()
    tmp = None
    bag = Path(a.bag) if a.bag else None
    if bag is None:
        tmp = Path(tempfile.mkdtemp(prefix='bag-read-'))
        bag = tmp / 'bag'
        _headless_bag(bag, a.seconds)
    from ladrc_bags import reader as reader_mod
    from ladrc_bags.columns import CdrColumns
    from ladrc_bags.errors import BagError
    from ladrc_bags.rows import RowPacker

    with open_bag(bag) as b:
        wanted = {t: None for t in b.topics}
        n = sum(b.message_counts.values())
        indexed = b._indexed_files()
        t0 = time.perf_counter()
        fast = b.read_topics(wanted)
        t1 = time.perf_counter()
        b._indexed_files = lambda: None  # rosbags' reader, messages batched into columns
        unindexed = b.read_topics(wanted)
        t2 = time.perf_counter()

        def no_columns(*_: object) -> None:
            raise BagError('bench: message by message')
        reader_mod.CdrColumns = no_columns  # rosbags' deserialize_cdr for every message
        try:
            slow = b.read_topics(wanted)
        finally:
            reader_mod.CdrColumns = CdrColumns
        t3 = time.perf_counter()
        cmd_type = b.topics[b.name('axis/velocity_command')]
        cmd = [d for _, d in b.raw('axis/velocity_command')]
        store = b.reader.typestore
    same = all(_same(fast[t], other[t]) for t in fast for other in (unindexed, slow))
    # the price of a string at 2 kHz: the command topic as recorded and with an empty commander
    dec = CdrColumns(cmd_type, store)
    cols = fast[next(t for t in fast if t.lstrip('/') == 'axis/velocity_command')]
    strings = ('timestamp_ns', 'stamp_s', 'commander', 'header.frame_id')
    fixed = RowPacker(cmd_type, store).pack(len(cmd), {
        k: v for k, v in cols.items() if k not in strings})
    times = {}
    for name, datas in (('with_string', cmd), ('fixed', fixed)):
        buf = np.frombuffer(b''.join(datas), dtype=np.uint8)
        size = np.fromiter(map(len, datas), dtype=np.int64, count=len(datas))
        start = np.concatenate([[0], np.cumsum(size[:-1])]).astype(np.int64)
        t4 = time.perf_counter()
        dec.decode(buf, start, size)
        times[name] = time.perf_counter() - t4
    if tmp is not None:
        shutil.rmtree(tmp, ignore_errors=True)
    print(json.dumps({'messages': n, 'indexed': indexed is not None,
                      'indexed_s': round(t1 - t0, 2), 'unindexed_s': round(t2 - t1, 2),
                      'per_message_s': round(t3 - t2, 2),
                      'indexed_msgs_per_s': round(n / (t1 - t0)),
                      'per_message_msgs_per_s': round(n / (t3 - t2)),
                      'speedup': round((t3 - t2) / (t1 - t0), 1), 'same_columns': same,
                      'command_messages': len(cmd),
                      'command_with_string_s': round(times['with_string'], 3),
                      'command_fixed_s': round(times['fixed'], 3)}))


def _same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    """Whether two topics' columns hold the same values (strings and NaN included)."""
    if a.keys() - {k for k in a if k.isupper()} != b.keys() - {k for k in b if k.isupper()}:
        return False
    for k, v in a.items():
        if k.isupper():
            continue
        w = b[k]
        if v.dtype == object or w.dtype == object:
            if list(v) != list(w):
                return False
        elif not np.array_equal(v, w, equal_nan=v.dtype.kind == 'f'):
            return False
    return True

if __name__ == '__main__':
    main()
