"""colcon test: the bridge's plain parts on their own (no LinuxCNC, no ROS)."""

import math

from ladrc_linuxcnc import protocol as p
from ladrc_linuxcnc.machine import set_ini_keys
from ladrc_linuxcnc.sequence import BridgeParams, Sequencer
from ladrc_linuxcnc.z_filter import filter_line

RUN = p.F_RUNNING | p.F_MACHINE_ON | p.F_HOMED


def sample(seq, flags, motion=0, x=0.0, v=0.0, dtg=0.0):
    return p.LcncSample(seq, seq * 1_000_000, x, 0.0, v, 50.0, v, dtg, 1.0, motion, seq, flags)


def test_frames_round_trip():
    reader = p.FrameReader()
    s = sample(3, RUN | p.F_SPINDLE_ON, p.MOTION_FEED, 1.5, 20.0, 4.0)
    o = p.HalOutputs(7, 0.5, p.O_AT_SPEED | p.O_BEAM, 2)
    data = p.pack_hello({'max_velocity_mm_s': 500.0}) + s.pack() + o.pack()
    reader.feed(data[:10])
    assert list(reader.frames()) == []
    reader.feed(data[10:])
    frames = list(reader.frames())
    assert frames[0] == (p.HELLO, {'version': p.VERSION, 'max_velocity_mm_s': 500.0})
    assert frames[1] == (p.SAMPLE, s) and frames[2] == (p.OUTPUTS, o)


def test_z_words_are_commented_out():
    assert filter_line('G0 X10 Y5 Z3\n') == ('G0 X10 Y5 (Z3)\n', 1)
    assert filter_line('G0 Z5\n') == ('G0 (Z5)\n', 1)
    assert filter_line('G1 X1 (no z here) F100\n') == ('G1 X1 (no z here) F100\n', 0)


def test_ini_keys_set_and_added():
    text = '[A]\nx = 1\n# c\n[B]\ny = 2\n'
    out = set_ini_keys(text, {('A', 'x'): 5, ('B', 'z'): 'q', ('C', 'k'): 1})
    assert out == '[A]\nx = 5\n# c\n[B]\ny = 2\nz = q\n[C]\nk = 1\n'


def test_a_contour_pierces_waits_cuts_and_ends():
    seq = Sequencer(BridgeParams(socket_path='/x', pierce_heights_mm=(3.0,),
                                 pierce_dwell_s=(0.1,)))
    seq.hello({'max_velocity_mm_s': 500.0, 'max_accel_mm_s2': 2000.0})
    ans = {'state': 0, 'substate': 0, 'gap_seq': 5, 'velocity_mm_s': 0.0}
    out = seq.step(sample(1, RUN | p.F_IDLE), ans, 0.0, 0.0)
    assert out.outputs.flags & p.O_HEIGHT_READY and not out.outputs.flags & p.O_AT_SPEED
    out = seq.step(sample(2, RUN | p.F_SPINDLE_ON), ans, 0.0, 0.1)  # M3
    assert [c[0] for c in out.commands] == ['pierce'] and out.motion['segment'] == 3
    assert not out.outputs.flags & (p.O_AT_SPEED | p.O_BEAM)
    ans = {**ans, 'state': 1, 'substate': 3, 'in_position': True}
    out = seq.step(sample(3, RUN | p.F_SPINDLE_ON), ans, 0.0, 0.2)
    assert out.outputs.flags & p.O_BEAM and not out.outputs.flags & p.O_AT_SPEED
    ans = {**ans, 'state': 3, 'substate': 4, 'ready_to_move': True}
    out = seq.step(sample(4, RUN | p.F_SPINDLE_ON), ans, 0.0, 0.3)
    assert out.outputs.flags & p.O_AT_SPEED
    out = seq.step(sample(5, RUN | p.F_SPINDLE_ON, p.MOTION_FEED, 1.0, 50.0), ans, 0.0, 0.4)
    assert out.motion['segment'] == 2 and out.motion['contour'] == 1
    ans = {**ans, 'state': 4, 'substate': 0}
    out = seq.step(sample(6, RUN, p.MOTION_TRAVERSE, 2.0, 10.0, 100.0), ans, 0.0, 0.5)  # M5, G0
    assert [c[0] for c in out.commands] == ['leapfrog']
    assert math.isclose(out.commands[0][1]['rapid_length_mm'], 100.0)
    out = seq.step(sample(7, p.F_MACHINE_ON | p.F_IDLE), ans, 0.0, 0.6)  # the program's end
    assert [c[0] for c in out.commands] == ['stop_follow'] and seq.log.finished
    assert seq.log.pierces == 1 and seq.log.moved_before_ready == 0
    assert seq.end_ready(ans, 0.7)


def test_a_fault_holds_the_feed_and_pauses():
    seq = Sequencer(BridgeParams(socket_path='/x'))
    ans = {'state': 4, 'substate': 0, 'gap_seq': 5, 'velocity_mm_s': 0.0}
    seq.step(sample(1, RUN), ans, 0.0, 0.0)
    out = seq.step(sample(2, RUN, p.MOTION_FEED, 1.0, 50.0), {**ans, 'state': 5,
                                                               'fault_reason': 'collision'},
                   0.0, 0.1)
    assert out.outputs.flags & p.O_FEED_HOLD and out.outputs.pause_count == 1
    assert 'collision' in seq.log.aborted
    # the log waits until LinuxCNC's samples show the feed held (its time is in the log)
    fault = {**ans, 'state': 5, 'fault_reason': 'collision'}
    seq.step(sample(3, RUN, p.MOTION_FEED, 1.0, 0.0), fault, 0.0, 0.15)
    assert not seq.end_ready(fault, 0.2)
    seq.step(sample(4, RUN | p.F_FEED_HOLD_IN | p.F_PAUSED), fault, 0.0, 0.25)
    assert seq.end_ready(fault, 0.3)
    assert seq.log.fault_holds[0]['feed_hold_after_ms'] == 150.0
