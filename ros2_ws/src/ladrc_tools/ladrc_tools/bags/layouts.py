"""PlotJuggler and Foxglove layouts of the main signals, generated from one list.

    python -m ladrc_tools.bags.layouts          # rewrites config/plotjuggler_layout.xml and
                                                # config/foxglove_layout.json (source tree)

The shipped files are these functions' output (a test compares them). Panels: gap (reading,
target, fused, true gap from the sim), TD (x1, x2), ESO (z1, z2, z3), command (applied,
unlimited, u0), state (state, limit flags, followed). Topic fields as ``ros2 bag record`` names
them (``/follow/status``).
"""

from __future__ import annotations

import json
from pathlib import Path
from xml.sax.saxutils import quoteattr

PANELS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ('gap mm', ('/follow/status/gap_mm', '/follow/status/target_gap_mm',
                '/follow/status/fused_gap_mm', '/sim/truth/true_gap_mm')),
    ('TD', ('/follow/status/td_x1_mm', '/follow/status/td_x2_mm_s')),
    ('ESO', ('/follow/status/eso_z1_mm', '/follow/status/eso_z2', '/follow/status/eso_z3')),
    ('command mm/s', ('/axis/velocity_command/velocity_mm_s',
                      '/follow/status/u_unlimited_mm_s', '/follow/status/u0_mm_s')),
    ('state', ('/follow/status/state', '/follow/status/limit_flags',
               '/follow/status/followed')),
)
"""(panel title, signals as ``/topic/field``)."""

COLORS = ('#1f77b4', '#d62728', '#2ca02c', '#ff7f0e', '#9467bd')


def plotjuggler_xml() -> str:
    """Return a PlotJuggler layout: one tab, the panels stacked, the ROS 2 bag loader."""
    n = len(PANELS)
    sizes = ';'.join([f'{1.0 / n:.6f}'] * n)
    lines = ["<?xml version='1.0' encoding='UTF-8'?>", '<root>',
             ' <tabbed_widget name="Main Window" parent="main_window">',
             '  <Tab containers="1" tab_name="ladrc">', '   <Container>',
             f'    <DockSplitter orientation="|" sizes="{sizes}" count="{n}">']
    for title, signals in PANELS:
        lines += [f'     <DockArea name={quoteattr(title)}>',
                  '      <plot flip_x="false" flip_y="false" mode="TimeSeries" style="Lines">',
                  '       <range top="1" bottom="0" right="1" left="0"/>', '       <limitY/>']
        lines += [f'       <curve name={quoteattr(s)} color="{COLORS[i % len(COLORS)]}"/>'
                  for i, s in enumerate(signals)]
        lines += ['      </plot>', '     </DockArea>']
    lines += ['    </DockSplitter>', '   </Container>', '  </Tab>',
              '  <currentTabIndex index="0"/>', ' </tabbed_widget>',
              ' <use_relative_time_offset enabled="1"/>',
              ' <Plugins>', '  <plugin ID="DataLoad ROS2 bags">',
              '   <use_header_stamp value="false"/>', '   <discard_large_arrays value="true"/>',
              '   <max_array_size value="100"/>', '   <boolean_strings_to_number value="true"/>',
              '   <remove_suffix_from_strings value="true"/>', '  </plugin>', ' </Plugins>',
              '</root>']
    return '\n'.join(lines) + '\n'


def foxglove_json() -> str:
    """Return a Foxglove layout: one Plot panel per entry of :data:`PANELS`, stacked."""
    config = {}
    ids = []
    for i, (title, signals) in enumerate(PANELS):
        pid = f'Plot!ladrc{i}'
        ids.append(pid)
        config[pid] = {
            'title': title, 'followingViewWidth': 10, 'showLegend': True,
            'legendDisplay': 'floating', 'isSynced': True, 'xAxisVal': 'timestamp',
            'paths': [{'value': _fox_path(s), 'enabled': True, 'timestampMethod': 'receiveTime',
                       'color': COLORS[j % len(COLORS)]} for j, s in enumerate(signals)],
        }
    layout: object = ids[-1]
    for pid in reversed(ids[:-1]):
        layout = {'first': pid, 'second': layout, 'direction': 'column',
                  'splitPercentage': 100.0 / (1 + _count(layout))}
    return json.dumps({'configById': config, 'globalVariables': {}, 'userNodes': {},
                       'playbackConfig': {'speed': 1}, 'layout': layout}, indent=2) + '\n'


def _fox_path(signal: str) -> str:
    topic, _, field = signal.rpartition('/')
    return f'{topic}.{field}'


def _count(layout: object) -> int:
    return 1 if isinstance(layout, str) else _count(layout['first']) + _count(layout['second'])


def config_dir() -> Path:
    """Return the package's config folder in the source tree."""
    return Path(__file__).resolve().parents[2] / 'config'


def main() -> None:
    """Rewrite the shipped layout files."""
    (config_dir() / 'plotjuggler_layout.xml').write_text(plotjuggler_xml(), encoding='utf-8')
    (config_dir() / 'foxglove_layout.json').write_text(foxglove_json(), encoding='utf-8')


if __name__ == '__main__':
    main()
