"""PlotJuggler and Foxglove layouts of the main signals, generated from one list.

    python -m ladrc_bags.layouts          # rewrites config/plotjuggler_layout.xml and
                                                # config/foxglove_layout.json (source tree)

The shipped files are these functions' output (a test compares them). PlotJuggler's panels:
gap (reading, target, fused, true gap from the sim), TD (x1, x2), ESO (z1, z2, z3), command
(applied, unlimited, u0), state (state, limit flags, followed). Topic fields as ``ros2 bag
record`` names them (``/follow/status``).

Foxglove's (:func:`foxglove_json`, docs/live-view.md): one layout for a bag and for the live
view (view_node), whose channels carry the topics' names and fields: gap and target, command,
a state timeline (state, sub-state, followed, fault and hold reasons), the fault log (the
view's ``/view/log``; a bag shows the reasons on the timeline), the events, the XY path of a
job coloured by the gap error, and the operator's calls (start, stop, reset, lift).
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


TITLE = 'foxglovePanelTitle'
"""Where a panel's title lives in the layout file's panel settings."""


def _plot(title: str, series: list[tuple[str, str, str]], **extra: object) -> dict:
    return {TITLE: title, 'followingViewWidth': 10, 'showLegend': True,
            'legendDisplay': 'floating', 'isSynced': True, 'xAxisVal': 'timestamp',
            'paths': [{'value': v, 'label': label, 'enabled': True,
                       'timestampMethod': 'receiveTime', 'color': color}
                      for v, label, color in series], **extra}


def _states(names: dict[int, str]) -> dict:
    return {'type': 'discrete', 'states': [{'value': str(v), 'label': n}
                                           for v, n in names.items()]}


XY_BANDS = ((0, 'closer > 0.2 mm', '#d62728'), (1, 'closer 0.05-0.2 mm', '#ff7f0e'),
            (2, 'within 0.05 mm', '#2ca02c'), (3, 'wider 0.05-0.2 mm', '#17becf'),
            (4, 'wider > 0.2 mm', '#1f77b4'), (5, 'not following', '#7f7f7f'))
"""The XY path's gap-error bands (ladrc_tools.node.view_channels.BANDS_MM): value, label,
colour."""
OPERATOR_CALLS = (('start', '/follow/start', '{"target_gap_mm": 1.0}', 'start at 1.0 mm',
                   '#2ca02c'),
                  ('stop', '/follow/stop', '{}', 'stop', '#d62728'),
                  ('reset', '/follow/reset_fault', '{}', 'reset fault', '#ff7f0e'),
                  ('lift', '/follow/lift', '{"mode": 1, "value_mm": 5.0, "velocity_mm_s": 0.0}',
                   'lift 5 mm', '#1f77b4'))
"""The Service Call panels: id, service, request, button text, colour."""


def foxglove_config() -> dict[str, dict]:
    """Return the Foxglove panels by id (``Type!name``; module docstring)."""
    from ladrc_contract.codes import FollowState, SubState

    s, truth, cmd = '/follow/status', '/sim/truth', '/axis/velocity_command'
    config: dict[str, dict] = {
        'Plot!gap': _plot('gap mm', [(f'{s}.gap_mm', 'reading', COLORS[0]),
                                     (f'{s}.target_gap_mm', 'target', COLORS[1]),
                                     (f'{s}.fused_gap_mm', 'fused', COLORS[2]),
                                     (f'{truth}.true_gap_mm', 'true (sim)', COLORS[3])]),
        'Plot!command': _plot('command mm/s', [(f'{cmd}.velocity_mm_s', 'sent', COLORS[0]),
                                               (f'{s}.u_unlimited_mm_s', 'unlimited',
                                                COLORS[1])]),
        'StateTransitions!state': {
            TITLE: 'state, sub-state, fault and hold reasons', 'isSynced': True,
            'showPoints': False, 'paths': [
                {'value': f'{s}.state', 'label': 'state', 'timestampMethod': 'receiveTime',
                 'customStates': _states({int(v): v.name for v in FollowState})},
                {'value': f'{s}.substate', 'label': 'sub-state',
                 'timestampMethod': 'receiveTime',
                 'customStates': _states({int(v): v.name for v in SubState})},
                {'value': f'{s}.followed', 'label': 'followed', 'timestampMethod': 'receiveTime'},
                {'value': f'{s}.fault_reason', 'label': 'fault',
                 'timestampMethod': 'receiveTime'},
                {'value': f'{s}.hold_reason', 'label': 'hold', 'timestampMethod': 'receiveTime'},
            ]},
        'Log!faults': {TITLE: 'fault log (live)', 'topicToRender': '/view/log',
                       'minLogLevel': 2, 'showLevel': True, 'showTime': True, 'showName': True},
        'RawMessages!events': {TITLE: 'follow events', 'topicPath': '/follow/events',
                               'expansion': 'none'},
        'Plot!xy': {
            TITLE: 'XY path, coloured by the gap error', 'xAxisVal': 'custom',
            'xAxisPath': {'value': f'{truth}.x_mm', 'enabled': True}, 'timeRange': 'all',
            'axisScalesMode': 'lockedScales', 'showLegend': True, 'legendDisplay': 'floating',
            'xAxisLabel': 'X mm', 'yAxisLabel': 'Y mm',
            'paths': [{'value': f'{truth}.y_mm', 'xValuePath': f'{truth}.x_mm',
                       'label': 'path', 'enabled': True, 'color': '#c7c7c7',
                       'timestampMethod': 'receiveTime'}]
            + [{'value': f'/view/xy_gap_error{{band=={b}}}.y_mm',
                'xValuePath': f'/view/xy_gap_error{{band=={b}}}.x_mm', 'label': label,
                'enabled': True, 'color': color, 'showLine': False,
                'timestampMethod': 'receiveTime'} for b, label, color in XY_BANDS]},
    }
    for name, service, request, text, color in OPERATOR_CALLS:
        config[f'ServiceCall!{name}'] = {TITLE: text, 'serviceName': service,
                                         'requestPayload': request, 'buttonText': text,
                                         'buttonColor': color, 'editingMode': False,
                                         'timeoutSeconds': 10}
    return config


def foxglove_json() -> str:
    """Return the Foxglove layout (module docstring): time series left, XY, log, calls right."""
    config = foxglove_config()

    def split(ids: list[str], direction: str) -> object:
        node: object = ids[-1]
        for pid in reversed(ids[:-1]):
            node = {'first': pid, 'second': node, 'direction': direction,
                    'splitPercentage': 100.0 / (1 + _count(node))}
        return node

    left = split(['Plot!gap', 'Plot!command', 'StateTransitions!state'], 'column')
    calls = split([f'ServiceCall!{c[0]}' for c in OPERATOR_CALLS], 'row')
    right = {'first': 'Plot!xy', 'second': {
        'first': 'Log!faults', 'second': {'first': 'RawMessages!events', 'second': calls,
                                          'direction': 'column', 'splitPercentage': 60.0},
        'direction': 'column', 'splitPercentage': 50.0}, 'direction': 'column',
        'splitPercentage': 45.0}
    layout = {'first': left, 'second': right, 'direction': 'row', 'splitPercentage': 60.0}
    return json.dumps({'configById': config, 'globalVariables': {}, 'userNodes': {},
                       'playbackConfig': {'speed': 1}, 'layout': layout}, indent=2) + '\n'


def _count(layout: object) -> int:
    return 1 if isinstance(layout, str) else _count(layout['first']) + _count(layout['second'])


def config_dir() -> Path:
    """Return the package's config folder in the source tree."""
    return Path(__file__).resolve().parents[1] / 'config'


def main() -> None:
    """Rewrite the shipped layout files."""
    (config_dir() / 'plotjuggler_layout.xml').write_text(plotjuggler_xml(), encoding='utf-8')
    (config_dir() / 'foxglove_layout.json').write_text(foxglove_json(), encoding='utf-8')


if __name__ == '__main__':
    main()
