#!/usr/bin/python3
"""A G-code program's path as LinuxCNC's own interpreter reads it (system Python, ``gcode``).

``gcode_path.py FILE [INITCODE]`` parses FILE with LinuxCNC's ``gcode`` module (the rs274ngc
interpreter AXIS previews with; nothing of ours parses G-code) and prints one JSON object:
``result`` (the interpreter's code; above ``min_error``: an error), ``error`` (its text and
line; ``error_text`` and ``line`` apart), ``cut_requests`` (how many times the moves go from
the spindle off to M3: the program's cut requests), ``moves``: ``[kind, line, x_mm, y_mm,
feed_mm_min, spindle]`` per canonical move in program order (``kind``: ``G0``, ``G1``,
``ARC``; ``spindle``: the M code of the spindle's modal group, 3, 4 or 5) and for an arc its
centre and turn (``cx_mm``, ``cy_mm``, ``turn``).

The interpreter reads tool data from LinuxCNC's shared memory: a program with T words needs
a running LinuxCNC (``INI_FILE_NAME`` its INI); without one it may crash (the caller reports
that, :func:`ladrc_linuxcnc.machine.read_program`).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile

MM_PER_IN = 25.4


class Canon:
    """The interpreter's canonical calls, recorded (the calls AXIS's canon answers)."""

    def __init__(self, parameter_file: str) -> None:
        self.parameter_file = parameter_file
        self.moves: list[list] = []
        self.line = 0
        self.state = None
        self.feed = 0.0

    def _spindle(self) -> int:
        return int(self.state.mcodes[2]) if self.state is not None else 5

    def next_line(self, st) -> None:  # noqa: D102
        self.line, self.state = st.sequence_number, st

    def get_external_angular_units(self) -> float:  # noqa: D102
        return 1.0

    def get_external_length_units(self) -> float:  # noqa: D102
        return 1.0 / MM_PER_IN  # internal units are inches: positions come in inches

    def get_axis_mask(self) -> int:  # noqa: D102
        return 3  # X and Y

    def get_block_delete(self) -> int:  # noqa: D102
        return 0

    def get_tool(self, _pocket: int):  # noqa: D102
        return (-1,) + (0.0,) * 12 + (0,)

    def check_abort(self) -> bool:  # noqa: D102
        return False

    def set_feed_rate(self, f: float) -> None:  # noqa: D102
        self.feed = f * MM_PER_IN

    def straight_traverse(self, x, y, *_rest) -> None:  # noqa: D102
        self.moves.append(['G0', self.line, x * MM_PER_IN, y * MM_PER_IN, 0.0, self._spindle()])

    def straight_feed(self, x, y, *_rest) -> None:  # noqa: D102
        self.moves.append(['G1', self.line, x * MM_PER_IN, y * MM_PER_IN, self.feed,
                           self._spindle()])

    def arc_feed(self, x1, y1, cx, cy, rot, *_rest) -> None:  # noqa: D102
        self.moves.append(['ARC', self.line, x1 * MM_PER_IN, y1 * MM_PER_IN, self.feed,
                           self._spindle(), cx * MM_PER_IN, cy * MM_PER_IN, int(rot)])

    def __getattr__(self, name: str):
        # every other canonical call (comments, dwell, offsets, plane, tool, spindle speed,
        # probe, ...) changes no XY path of a laser program: accepted, not recorded
        if name.startswith('_'):
            raise AttributeError(name)
        return lambda *args: None


def main(argv: list[str]) -> int:
    """Parse ``argv[0]``; print the JSON (module docstring)."""
    import gcode

    if not argv:
        print('gcode_path: usage: gcode_path.py FILE [INITCODE]', file=sys.stderr)
        return 2
    os.environ.setdefault('INI_FILE_NAME', '/dev/null')
    with tempfile.TemporaryDirectory(prefix='ladrc-gcode-') as tmp:
        canon = Canon(os.path.join(tmp, 'parse.var'))
        open(canon.parameter_file, 'w').close()
        result, seq = gcode.parse(argv[0], canon, 'G21', argv[1] if len(argv) > 1 else '')
    error = text = ''
    if result > gcode.MIN_ERROR:
        text = gcode.strerror(result)
        error = f'{text} (line {seq})'
    spindle = [m[5] for m in canon.moves]
    cut_requests = sum(1 for a, b in zip([5, *spindle], spindle, strict=False)
                       if b == 3 and a != 3)
    print(json.dumps({'result': int(result), 'min_error': int(gcode.MIN_ERROR),
                      'error': error, 'error_text': text, 'line': int(seq),
                      'cut_requests': cut_requests, 'moves': canon.moves}))
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
