"""The nodes' CDR decoder (ros/cdr.py) gives exactly what rclpy's deserialisation gives.

Random messages of every type an estimator reads (and a few more, for the field kinds those do
not have) are serialised by rclpy and decoded both ways; the results must match field by field:
the same classes, the same container types (numpy arrays of the same dtype, array.array of the
same typecode, lists), the same bits of every float (NaN payloads included)."""

from __future__ import annotations

import array
import math
import struct
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message
from rosidl_parser import definition as rosidl

from terrain_estimation.ros.cdr import decoder_for
from terrain_estimation.vehicles import VEHICLES, estimator_parameters, get_vehicle


def _input_types() -> list[type]:
    types: dict[str, type] = {}
    for name in VEHICLES:
        entry = get_vehicle(name)
        adapter = entry.make_adapter(estimator_parameters(entry), "/t")
        for spec in adapter.inputs:
            types[f"{spec.msg_type.__module__}.{spec.msg_type.__name__}"] = spec.msg_type
    return list(types.values())


INPUT_TYPES = _input_types()


def _extra_types() -> list[type]:
    from nav_msgs.msg import OccupancyGrid, Odometry
    from sensor_msgs.msg import BatteryState, CompressedImage, Joy, NavSatFix, Range
    from shape_msgs.msg import MeshTriangle

    # Odometry: nested arrays and two strings; NavSatFix: int8, uint8, uint16, a
    # fixed array after a variable part; BatteryState: float32, bool, sequences of
    # float32 and a string sequence after them; Range: float32 only; Joy: int32
    # and float32 sequences; OccupancyGrid: an int8 sequence after nested uint32,
    # float32 and doubles; CompressedImage: a uint8 sequence; MeshTriangle: a
    # fixed uint32 array.
    return [Odometry, NavSatFix, BatteryState, Range, Joy, OccupancyGrid, CompressedImage, MeshTriangle]


ALL_TYPES = INPUT_TYPES + _extra_types()

_INT_RANGES = {
    "int8": (-(2**7), 2**7 - 1),
    "uint8": (0, 2**8 - 1),
    "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "uint32": (0, 2**32 - 1),
    "int64": (-(2**63), 2**63 - 1),
    "uint64": (0, 2**64 - 1),
}
_FLOATS = st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from([0.0, -0.0, 1e-310, float("nan")])
_FLOAT32 = st.floats(width=32, allow_nan=True, allow_infinity=True)
_TEXT = st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=12)


def _value(draw: Any, t: Any) -> Any:
    if isinstance(t, rosidl.BasicType):
        name = t.typename
        if name == "double":
            return draw(_FLOATS)
        if name == "float":
            return draw(_FLOAT32)
        if name == "boolean":
            return draw(st.booleans())
        lo, hi = _INT_RANGES[name]
        return draw(st.integers(lo, hi) | st.sampled_from([lo, hi, 0]))
    if isinstance(t, (rosidl.UnboundedString, rosidl.BoundedString)):
        return draw(_TEXT)
    if isinstance(t, rosidl.NamespacedType):
        module = __import__(".".join(t.namespaces), fromlist=[t.name])
        return _fill(draw, getattr(module, t.name)())
    if isinstance(t, rosidl.Array):
        return [_value(draw, t.value_type) for _ in range(t.size)]
    if isinstance(t, (rosidl.UnboundedSequence, rosidl.BoundedSequence)):
        return [_value(draw, t.value_type) for _ in range(draw(st.integers(0, 4)))]
    raise AssertionError(f"no strategy for {t!r}")


def _fill(draw: Any, msg: Any) -> Any:
    for name, t in zip(msg.get_fields_and_field_types(), msg.SLOT_TYPES, strict=True):
        setattr(msg, name, _value(draw, t))
    return msg


def assert_same(expected: Any, got: Any, path: str = "msg") -> None:
    """Equal field by field, container types and float bits included."""
    assert type(got) is type(expected), f"{path}: {type(got)} instead of {type(expected)}"
    if hasattr(expected, "get_fields_and_field_types"):
        for name in expected.get_fields_and_field_types():
            assert_same(getattr(expected, name), getattr(got, name), f"{path}.{name}")
        assert got._check_fields == expected._check_fields
    elif isinstance(expected, np.ndarray):
        assert got.dtype == expected.dtype and got.shape == expected.shape, path
        assert got.tobytes() == expected.tobytes(), f"{path}: {got} != {expected}"
        assert got.flags.writeable and got.flags.owndata == expected.flags.owndata, path
    elif isinstance(expected, array.array):
        assert got.typecode == expected.typecode and got.tobytes() == expected.tobytes(), path
    elif isinstance(expected, list):
        assert len(got) == len(expected), path
        for i, (e, g) in enumerate(zip(expected, got, strict=True)):
            assert_same(e, g, f"{path}[{i}]")
    elif isinstance(expected, float):
        assert struct.pack("<d", got) == struct.pack("<d", expected), f"{path}: {got!r} != {expected!r}"
    else:
        assert got == expected, f"{path}: {got!r} != {expected!r}"


def test_every_estimator_input_type_has_a_decoder():
    names = sorted(t.__name__ for t in INPUT_TYPES)
    assert names == ["Imu", "JointState", "PointStamped", "TwistStamped", "WrenchStamped"]
    for t in ALL_TYPES:
        assert decoder_for(t) is not None, t


@pytest.mark.parametrize("msg_type", ALL_TYPES, ids=lambda t: t.__name__)
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_decoded_equals_rclpy(msg_type, data):
    msg = _fill(data.draw, msg_type())
    raw = serialize_message(msg)
    assert_same(deserialize_message(raw, msg_type), decoder_for(msg_type)(raw))


_DTYPES = {
    "double": "f8",
    "float": "f4",
    "int8": "i1",
    "uint8": "u1",
    "int16": "i2",
    "uint16": "u2",
    "int32": "i4",
    "uint32": "u4",
    "int64": "i8",
    "uint64": "u8",
}


def _to_rosbags(value: Any, t: Any, store: Any) -> Any:
    """The rclpy value ``value`` of rosidl type ``t`` as rosbags represents it."""
    if isinstance(t, rosidl.NamespacedType):
        cls = store.types["/".join((*t.namespaces, t.name))]
        fields = zip(value.get_fields_and_field_types(), value.SLOT_TYPES, strict=True)
        return cls(**{name: _to_rosbags(getattr(value, name), ft, store) for name, ft in fields})
    if isinstance(t, rosidl.AbstractNestedType) and isinstance(t.value_type, rosidl.BasicType):
        return np.array(list(value), dtype=_DTYPES[t.value_type.typename])
    if isinstance(t, rosidl.AbstractNestedType):
        return list(value)
    return value


def _big_endian(msg: Any) -> bytes:
    """``msg`` as big-endian CDR, serialised by rosbags (an independent serialiser; rclpy writes
    only little-endian)."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    cls = type(msg)
    t = rosidl.NamespacedType([cls.__module__.split(".")[0], "msg"], cls.__name__)
    name = "/".join((*t.namespaces, t.name))
    return bytes(store.serialize_cdr(_to_rosbags(msg, t, store), name, little_endian=False))


@pytest.mark.parametrize("msg_type", ALL_TYPES, ids=lambda t: t.__name__)
@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_big_endian_cdr_decodes_to_the_same_message(msg_type, data):
    msg = _fill(data.draw, msg_type())
    raw = serialize_message(msg)
    be = _big_endian(msg)
    assert be[:2] == b"\x00\x00"
    assert_same(deserialize_message(raw, msg_type), decoder_for(msg_type)(be))


def test_what_it_does_not_trust_goes_to_rclpy():
    from geometry_msgs.msg import PointStamped

    decode = decoder_for(PointStamped)
    msg = PointStamped()
    msg.header.frame_id = "v1/road"
    msg.point.z = 0.25
    raw = bytearray(serialize_message(msg))
    # Another encapsulation (here a made-up XCDR2 id over the same bytes): rclpy decides.
    other = bytes(b"\x00\x07" + raw[2:])
    assert_same(deserialize_message(other, PointStamped), decode(other))
    # A string without its NUL, an embedded NUL, bytes cut short: rclpy's result or its error.
    text = 16  # encapsulation, stamp (sec, nanosec), frame_id's length: its characters start here
    assert raw[text : text + 8] == b"v1/road\x00"
    no_nul = bytes(raw[: text + 7] + b"d" + raw[text + 8 :])  # "v1/road\0" -> "v1/roadd"
    embedded = bytes(raw[: text + 2] + b"\x00" + raw[text + 3 :])  # "v1\0road\0": rclpy reads "v1"
    for bad in (no_nul, embedded, bytes(raw[:30]), b"", b"\x00\x01"):
        try:
            expected = deserialize_message(bad, PointStamped)
        except RuntimeError as exc:
            with pytest.raises(type(exc)):
                decode(bad)
        else:
            assert_same(expected, decode(bad))


def test_types_it_cannot_decode_get_no_decoder():
    from diagnostic_msgs.msg import DiagnosticArray  # a sequence of messages
    from std_msgs.msg import Byte, String  # octet

    assert decoder_for(DiagnosticArray) is None
    assert decoder_for(Byte) is None
    assert decoder_for(String) is not None


def test_nan_payload_and_extremes_survive():
    from sensor_msgs.msg import Imu

    msg = Imu()
    quiet_nan = struct.unpack("<d", struct.pack("<Q", 0x7FF8_0000_DEAD_BEEF))[0]
    msg.linear_acceleration.z = quiet_nan
    msg.orientation_covariance[0] = -1.0
    msg.angular_velocity_covariance[8] = math.inf
    msg.header.stamp.sec = -(2**31)
    msg.header.stamp.nanosec = 2**32 - 1
    raw = serialize_message(msg)
    assert_same(deserialize_message(raw, Imu), decoder_for(Imu)(raw))
