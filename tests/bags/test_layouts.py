"""The shipped PlotJuggler and Foxglove layouts: generated, parseable, real fields."""

from __future__ import annotations

import json
from xml.etree import ElementTree

from ladrc_bags.layouts import PANELS, config_dir, foxglove_json, plotjuggler_xml
from ladrc_bags.typestore import ladrc_typestore
from ladrc_contract.topics import TOPIC_TYPES


def test_shipped_layouts_are_generated():
    # regenerate with: scripts/in-env python -m ladrc_bags.layouts
    assert (config_dir() / 'plotjuggler_layout.xml').read_text() == plotjuggler_xml()
    assert (config_dir() / 'foxglove_layout.json').read_text() == foxglove_json()


def test_every_signal_is_a_field_of_its_topic():
    store = ladrc_typestore()
    for _, signals in PANELS:
        for s in signals:
            topic, _, field = s.rpartition('/')
            msgtype = TOPIC_TYPES[topic.lstrip('/')]
            names = [f[0] for f in store.fielddefs[msgtype][1]]
            assert field in names, (s, names)


def test_layouts_parse_and_hold_every_signal():
    root = ElementTree.fromstring(plotjuggler_xml())
    curves = [c.get('name') for c in root.iter('curve')]
    assert curves == [s for _, sig in PANELS for s in sig]
    fox = json.loads(foxglove_json())
    # the Foxglove layout (bags and the live view, docs/live-view.md): every path on a
    # contract topic is a field of it (tests/ros/test_view_node.py: of the live channel too)
    store = ladrc_typestore()
    paths = [p[k] for c in fox['configById'].values() for p in c.get('paths', [])
             for k in ('value', 'xValuePath') if k in p]
    assert {'/follow/status.gap_mm', '/follow/status.target_gap_mm',
            '/axis/velocity_command.velocity_mm_s', '/follow/status.fault_reason',
            '/sim/truth.x_mm'} <= set(paths)
    for path in paths:
        topic, _, field = path.rpartition('.')
        if topic.lstrip('/') in TOPIC_TYPES:
            names = [f[0] for f in store.fielddefs[TOPIC_TYPES[topic.lstrip('/')]][1]]
            assert field in names, path
    # the split tree holds every panel once
    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node['first']) + leaves(node['second'])
    assert sorted(leaves(fox['layout'])) == sorted(fox['configById'])
