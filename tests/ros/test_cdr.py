"""The fast CDR packer of the publish path equals the reference serializers."""

from __future__ import annotations

from msgfill import cdr_padding, fill_rclpy, to_rosbags
import pytest

rclpy = pytest.importorskip('rclpy')
from ladrc_bags.typestore import ladrc_typestore, msg_definitions  # noqa: E402
from ladrc_contract.cdr import CdrPacker, flat_fields  # noqa: E402
import ladrc_msgs.msg  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402

MESSAGES = sorted(name.rsplit('/', 1)[1] for name in msg_definitions())


def _leaf(msg, dotted: str):
    for part in dotted.split('.'):
        msg = getattr(msg, part)
    return msg


@pytest.mark.parametrize('name', MESSAGES)
@pytest.mark.parametrize('salt', [0, 1, 2, 3])  # different string lengths shift the alignment
def test_packer_matches_rosbags_and_rclpy(name, salt):
    store = ladrc_typestore()
    typename = f'ladrc_msgs/msg/{name}'
    msg = fill_rclpy(getattr(ladrc_msgs.msg, name)(), salt=salt)
    packer = CdrPacker(typename)
    ours = packer.pack([_leaf(msg, f) for f, _ in packer.fields])
    reference = bytes(store.serialize_cdr(to_rosbags(msg, store, typename), typename))
    assert ours == reference
    theirs = serialize_message(msg)
    padding = cdr_padding(store, typename, to_rosbags(msg, store, typename))
    assert len(ours) == len(theirs)
    assert all(ours[i] == theirs[i] for i in range(len(ours)) if i not in padding)


def _rosbags_flat(store, typename: str, prefix: str = '') -> list[tuple[str, str]]:
    out = []
    for name, (node, detail) in store.fielddefs[typename][1]:
        if node.name == 'NAME':
            out += _rosbags_flat(store, detail, f'{prefix}{name}.')
        else:
            out.append((f'{prefix}{name}', detail[0]))
    return out


@pytest.mark.parametrize('name', MESSAGES)
def test_layout_from_rclpy_classes_equals_the_msg_files(name):
    # flat_fields reads the rclpy-generated classes; rosbags parses the .msg files
    typename = f'ladrc_msgs/msg/{name}'
    assert flat_fields(typename) == _rosbags_flat(ladrc_typestore(), typename)


@pytest.mark.parametrize(('typename', 'fields'), [
    ('std_msgs/msg/Header', [('stamp.sec', 'int32'), ('stamp.nanosec', 'uint32'),
                             ('frame_id', 'string')]),
    ('std_msgs/msg/Bool', [('data', 'bool')]),
    ('std_msgs/msg/Byte', [('data', 'byte')]),
    ('std_msgs/msg/Char', [('data', 'uint8')]),  # .msg char is an IDL uint8
    ('std_msgs/msg/Float32', [('data', 'float32')]),
])
def test_primitive_names(typename, fields):
    assert flat_fields(typename) == fields


@pytest.mark.parametrize('typename', ['std_msgs/msg/Float64MultiArray',  # sequences
                                      'std_msgs/msg/NoSuchMessage', 'not_a_type'])
def test_unsupported_types_are_refused(typename):
    with pytest.raises(ValueError):
        CdrPacker(typename)


@pytest.mark.parametrize('name', MESSAGES)
@pytest.mark.parametrize('salt', [0, 1, 2, 3])
def test_unpack_reads_back_what_rclpy_serialized(name, salt):
    """A loop takes raw bytes from its reader: the unpacked leaves are the message's values."""
    typename = f'ladrc_msgs/msg/{name}'
    msg = fill_rclpy(getattr(ladrc_msgs.msg, name)(), salt=salt)
    packer = CdrPacker(typename)
    values = packer.unpack(serialize_message(msg))
    assert values == [_leaf(msg, f) for f, _ in packer.fields]
    assert packer.pack(values) == packer.pack(values)  # and packs again as it was


@pytest.mark.parametrize('mangle', [
    lambda b: b[:len(b) // 2],                 # short
    lambda b: b'\x00\x00' + b[2:],             # big endian / another encoding
    lambda b: b[:-1] + b'\x01',                # the last string loses its terminator
    lambda b: b'',
])
def test_unpack_refuses_what_is_not_the_message(mangle):
    packer = CdrPacker('ladrc_msgs/msg/AxisFeedback')
    data = serialize_message(fill_rclpy(ladrc_msgs.msg.AxisFeedback(), salt=1))
    with pytest.raises(ValueError):
        packer.unpack(mangle(data))
