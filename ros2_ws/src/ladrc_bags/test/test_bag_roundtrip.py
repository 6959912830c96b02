"""colcon test: a bag written by the package reads back (no ROS processes).

The project's full suite is tests/ at the repository root (make test).
"""

from ladrc_bags import BagWriter, RowPacker, open_bag
import numpy as np


def test_written_bag_reads_back(tmp_path):
    rows = RowPacker('ladrc_msgs/msg/VelocityCommand').pack(
        100, {'seq': np.arange(100), 'velocity_mm_s': np.linspace(-1, 1, 100)})
    with BagWriter(tmp_path / 'bag') as w:
        for i, row in enumerate(rows):
            w.write_raw('axis/velocity_command', 10**9 + i * 500_000, row)
    with open_bag(tmp_path / 'bag') as b:
        cols = b.columns('/axis/velocity_command')
        assert b.seq_loss('axis/velocity_command') == (100, 0)
    assert np.allclose(cols['velocity_mm_s'], np.linspace(-1, 1, 100))
