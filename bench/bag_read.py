"""Reading a bag into columns: through the MCAP indexes vs message by message (rosbags).

    scripts/in-env python bench/bag_read.py [--bag DIR] [--seconds 600]

Without ``--bag``, a headless run of ``--seconds`` (a sine sheet, the shipped controller) is
written as a bag first. Then every topic, every field, is read into numpy columns twice in
this process: through the MCAP chunk and message indexes (``Bag.read_topics``, the tools'
path) and message by message through rosbags (the same call with the indexed path switched
off). Both results are checked equal. Last line: JSON with the messages, both wall times,
messages per second and the speed-up.
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

from ladrc_tools.bags.bag import open_bag  # noqa: E402


def _headless_bag(path: Path, seconds: float) -> None:
    from bag_scale import shift_scenario  # the same shift as the other bag benches
    from ladrc_follow.control.follow import FollowController
    from ladrc_follow.control.params import ControllerParams, dump_params
    from ladrc_sim.headless.runner import run
    from ladrc_sim.headless.scenario import scenario_from_dict
    from ladrc_tools.bags.bag import write_run_bag

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
    with open_bag(bag) as b:
        wanted = {t: None for t in b.topics}
        n = sum(b.message_counts.values())
        indexed = b._indexed_files()
        t0 = time.perf_counter()
        fast = b.read_topics(wanted)
        t1 = time.perf_counter()
        b._indexed_files = lambda: None  # message by message
        slow = b.read_topics(wanted)
        t2 = time.perf_counter()
    same = all(fast[t].keys() == slow[t].keys() and all(
        np.array_equal(fast[t][k], slow[t][k], equal_nan=fast[t][k].dtype.kind == 'f')
        for k in fast[t] if fast[t][k].dtype != object) for t in fast)
    if tmp is not None:
        shutil.rmtree(tmp, ignore_errors=True)
    print(json.dumps({'messages': n, 'indexed': indexed is not None,
                      'indexed_s': round(t1 - t0, 2), 'per_message_s': round(t2 - t1, 2),
                      'indexed_msgs_per_s': round(n / (t1 - t0)),
                      'per_message_msgs_per_s': round(n / (t2 - t1)),
                      'speedup': round((t2 - t1) / (t1 - t0), 1), 'same_columns': same}))


if __name__ == '__main__':
    main()
