"""Decoding serialised input messages into their rclpy classes, cheaper than rclpy does.

Why: rclpy's deserialisation builds a message through the generated class's
constructors and checked property setters, one nested message at a time. For
the contract's small sensor messages that costs more than the estimator's own
work on them: about 9 µs for a ``geometry_msgs/PointStamped`` and 17 µs for a
``sensor_msgs/Imu`` here, against about 2 µs for this module's decoder of the
same bytes. At a 1 kHz profile replayed at 20x real time, that difference is a
fifth of the one thread that runs every callback (``make bench-load``).

What it does: :func:`decoder_for` compiles, once per message class, a Python
function that reads the CDR (XCDR1, as Fast DDS and Cyclone DDS publish ROS 2
messages) with :mod:`struct` and fills an instance of the same rclpy class
directly: the objects an input check or an adapter sees are those rclpy would
give (same classes, same field types: ``numpy.ndarray`` for fixed arrays,
``array.array`` for numeric sequences, ``list`` of ``str`` for string
sequences), which ``test/test_cdr.py`` checks field by field, bit for bit, on
random messages of every type the estimators read.

What it does not: anything it is not sure of goes to
``rclpy.serialization.deserialize_message``, which stays the reference:
another encapsulation than plain CDR (XCDR2, parameter lists), a string with
an embedded or missing NUL or invalid UTF-8, data shorter than the type
needs. A class with a field type the compiler does not handle (``char``,
``octet``, wide strings, sequences of messages) or whose generated layout
(the ``_field`` slots) is not the one it fills gets no decoder at all
(:func:`decoder_for` returns None).
"""

from __future__ import annotations

import array
import struct
import sys
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
from rclpy.serialization import deserialize_message
from rosidl_parser import definition as rosidl

__all__ = ["decoder_for", "Decoder", "StampedLayout", "stamped_layout"]

Decoder = Callable[[bytes], Any]

# rosidl basic type -> (struct code, size, array.array typecode, numpy dtype); sizes are CDR's.
_PRIMITIVES: dict[str, tuple[str, int, str, str]] = {
    "float": ("f", 4, "f", "f4"),
    "double": ("d", 8, "d", "f8"),
    "boolean": ("?", 1, "", ""),
    "int8": ("b", 1, "b", "i1"),
    "uint8": ("B", 1, "B", "u1"),
    "int16": ("h", 2, "h", "i2"),
    "uint16": ("H", 2, "H", "u2"),
    "int32": ("i", 4, "i", "i4"),
    "uint32": ("I", 4, "I", "u4"),
    "int64": ("q", 8, "q", "i8"),
    "uint64": ("Q", 8, "Q", "u8"),
}

_CDR_BE = b"\x00\x00"  # encapsulation identifiers (big-endian 16 bit, then 2 option bytes)
_CDR_LE = b"\x00\x01"


class _UnsupportedError(Exception):
    """A field type the compiler does not handle: the class gets no decoder."""


class _FallbackError(Exception):
    """Bytes this decoder will not interpret: rclpy's deserialisation decides."""


def _string(b: bytes, o: int) -> tuple[str, int]:
    """The CDR string at ``o`` (uint32 length with its NUL, aligned by the caller) and the offset after it."""
    (n,) = _U32[b[1]].unpack_from(b, o)
    o += 4
    end = o + n - 1
    if n < 1 or end >= len(b) or b[end] != 0:
        raise _FallbackError
    raw = b[o:end]
    if 0 in raw:  # rclpy's C string would stop at the first NUL
        raise _FallbackError
    return raw.decode(), end + 1


def _strings(b: bytes, o: int, n: int) -> tuple[list[str], int]:
    out = []
    for _ in range(n):
        o += (4 - o) & 3
        s, o = _string(b, o)
        out.append(s)
    return out, o


_U32 = {0: struct.Struct(">I"), 1: struct.Struct("<I")}  # by the encapsulation's second byte


class _Compiler:
    """Generates the source of one decoding function for one byte order.

    Offsets: ``o`` indexes the whole buffer; CDR aligns relative to the payload,
    which starts after the 4-byte encapsulation header, hence ``(4 - o) & (a - 1)``.
    What is known at compile time of ``(o - 4) mod 8`` (``mod``, ``res``) lets runs
    of fixed-size fields be read by one ``struct`` call with their padding inside.
    """

    def __init__(self, endian: str) -> None:
        self.endian = endian
        self.lines: list[str] = []
        self.env: dict[str, Any] = {
            "_new": object.__new__,
            "_string": _string,
            "_strings": _strings,
            "_array": array.array,
            "_frombuffer": np.frombuffer,
            "_FallbackError": _FallbackError,
            "_swap": endian == ">" if sys.byteorder == "little" else endian == "<",
        }
        self.count = 0
        self.mod, self.res = 8, 0
        self.fmt = ""
        self.targets: list[str] = []

    def name(self, prefix: str) -> str:
        self.count += 1
        return f"{prefix}{self.count}"

    def const(self, value: Any, prefix: str = "_c") -> str:
        key = self.name(prefix)
        self.env[key] = value
        return key

    def emit(self, line: str) -> None:
        self.lines.append("    " + line)

    # -- fixed-size runs --------------------------------------------------------------
    def flush(self) -> None:
        if not self.fmt:
            return
        packer = struct.Struct(self.endian + self.fmt)
        s = self.const(packer, "_s")
        if self.targets:
            self.emit(f"({', '.join(self.targets)},) = {s}.unpack_from(b, o)")
        self.emit(f"o += {packer.size}")
        self.fmt, self.targets = "", []

    def align(self, a: int) -> None:
        if a == 1:
            return
        if a <= self.mod:  # the padding is known now
            pad = (-self.res) % a
            if pad:
                self.fmt += f"{pad}x"
            self.res = (self.res + pad) % self.mod
        else:
            self.flush()
            self.emit(f"o += (4 - o) & {a - 1}")
            self.mod, self.res = a, 0

    def forget(self, mod: int) -> None:
        """After a variable-length part: only ``(o - 4) ≡ 0 (mod mod)`` is known."""
        self.mod, self.res = mod, 0

    def primitive(self, code: str, size: int, target: str) -> None:
        self.align(size)
        self.fmt += code
        self.targets.append(target)
        self.res = (self.res + size) % self.mod

    # -- fields -----------------------------------------------------------------------
    def message(self, cls: type) -> str:
        """Code creating an instance of ``cls`` from the bytes; returns its variable."""
        fields = list(cls.get_fields_and_field_types())  # type: ignore[attr-defined]
        slots = list(getattr(cls, "__slots__", ()))
        if [s for s in slots if s != "_check_fields"] != ["_" + f for f in fields] or len(fields) != len(
            cls.SLOT_TYPES  # type: ignore[attr-defined]
        ):
            raise _UnsupportedError(f"{cls.__name__}: generated layout not recognised")
        var = self.name("m")
        self.emit(f"{var} = _new({self.const(cls, '_cls')})")
        if "_check_fields" in slots:
            self.emit(f"{var}._check_fields = {self.const(cls()._check_fields)}")
        for field, slot_type in zip(fields, cls.SLOT_TYPES, strict=True):  # type: ignore[attr-defined]
            self.field(f"{var}._{field}", slot_type)
        return var

    def field(self, target: str, t: Any) -> None:
        if isinstance(t, rosidl.BasicType):
            code, size, _, _ = self.basic(t)
            self.primitive(code, size, target)
        elif isinstance(t, rosidl.NamespacedType):
            sub = self.message(_message_class(t))
            self.emit(f"{target} = {sub}")
        elif isinstance(t, (rosidl.UnboundedString, rosidl.BoundedString)):
            self.align(4)
            self.flush()
            self.emit(f"{target}, o = _string(b, o)")
            self.forget(1)
        elif isinstance(t, rosidl.Array):
            self.array(target, t.value_type, str(t.size))
        elif isinstance(t, (rosidl.UnboundedSequence, rosidl.BoundedSequence)):
            n = self.name("n")
            self.primitive("I", 4, n)
            self.flush()
            self.sequence(target, t.value_type, n)
        else:
            raise _UnsupportedError(f"field type {type(t).__name__}")

    @staticmethod
    def basic(t: Any) -> tuple[str, int, str, str]:
        if t.typename not in _PRIMITIVES:
            raise _UnsupportedError(f"basic type {t.typename}")
        return _PRIMITIVES[t.typename]

    def array(self, target: str, value_type: Any, n: str) -> None:
        """A fixed-size array: numeric ones are numpy arrays in rclpy, strings a list."""
        if isinstance(value_type, (rosidl.UnboundedString, rosidl.BoundedString)):
            self.align(4)
            self.flush()
            self.strings(target, n)
            return
        code, size, _, dtype = self.element(value_type, "array")
        if not dtype:
            raise _UnsupportedError("array of booleans")
        self.align(size)
        self.flush()
        dt = self.const(np.dtype(self.endian + dtype))
        native = self.const(np.dtype(dtype))
        self.emit(f"{target} = _frombuffer(b, {dt}, {n}, o).astype({native})")
        self.emit(f"o += {n} * {size}")
        self.res = (self.res + int(n) * size) % self.mod

    def strings(self, target: str, n: str) -> None:
        """``n`` strings of an array or a sequence (the offset at them): a list in rclpy."""
        self.emit(f"{target}, o = _strings(b, o, {n})")
        self.forget(1)

    def element(self, value_type: Any, container: str) -> tuple[str, int, str, str]:
        """:meth:`basic` of the element type of an array or a sequence (``container``): messages are refused."""
        if not isinstance(value_type, rosidl.BasicType):
            raise _UnsupportedError(f"{container} of messages")
        return self.basic(value_type)

    def sequence(self, target: str, value_type: Any, n: str) -> None:
        """A sequence (count just read into ``n``): numeric ones are array.array in rclpy."""
        if isinstance(value_type, (rosidl.UnboundedString, rosidl.BoundedString)):
            self.strings(target, n)
            return
        code, size, typecode, _ = self.element(value_type, "sequence")
        if not typecode:
            raise _UnsupportedError("sequence of booleans")
        # An empty sequence has no element to align (Fast CDR writes no padding for it).
        if size > 1:
            self.emit(f"if {n}: o += (4 - o) & {size - 1}")
        end = self.name("e")
        self.emit(f"{end} = o + {n} * {size}")
        self.emit(f"if {end} > len(b): raise _FallbackError")
        self.emit(f"{target} = _array({typecode!r}, b[o:{end}])")
        self.emit(f"if _swap: {target}.byteswap()")
        self.emit(f"o = {end}")
        self.forget(min(size, 4))

    def build(self, cls: type) -> Callable[[bytes], Any]:
        self.emit("o = 4")
        var = self.message(cls)
        self.flush()
        self.emit(f"return {var}")
        source = "def decode(b):\n" + "\n".join(self.lines) + "\n"
        namespace = dict(self.env)
        exec(compile(source, f"<cdr decoder {cls.__module__}.{cls.__name__} {self.endian}>", "exec"), namespace)
        decode: Callable[[bytes], Any] = namespace["decode"]
        decode.__doc__ = source  # what was generated, for anyone debugging it
        return decode


def _message_class(t: Any) -> type:
    module = __import__(".".join(t.namespaces), fromlist=[t.name])
    return getattr(module, t.name)


@cache
def decoder_for(msg_type: type) -> Decoder | None:
    """A function ``bytes -> msg_type instance`` equal to rclpy's ``deserialize_message``, or
    None when ``msg_type`` has a field this module does not decode (see the module's text).

    The returned function hands every buffer it does not fully trust to
    ``deserialize_message`` (which raises on bytes that are not the type).
    """
    try:
        little = _Compiler("<").build(msg_type)
        big = _Compiler(">").build(msg_type)
    except _UnsupportedError:
        return None

    def decode(data: bytes) -> Any:
        header = data[:2]
        try:
            if header == _CDR_LE:
                return little(data)
            if header == _CDR_BE:
                return big(data)
        except (_FallbackError, struct.error, ValueError, UnicodeDecodeError):
            pass
        return deserialize_message(data, msg_type)

    decode.__qualname__ = f"decode_{msg_type.__name__}"
    return decode


# -- decoding in bulk ----------------------------------------------------------------------------------------
#
# A stamped sample (a Header, then float64s only: ``geometry_msgs/PointStamped``, ``sensor_msgs/Imu``) whose
# frame is the one expected has a fixed length and a fixed place for each field: the messages of one topic can
# be decoded all at once as a numpy record array, with no per-message object. The offline replay does that for
# the samples it may judge on arrays (:meth:`~terrain_estimation.ros.validation.InputGuard.stateless_ok`);
# anything else (another length, frame, encapsulation) goes through :func:`decoder_for` one by one.


@dataclass(frozen=True)
class StampedLayout:
    """Where plain little-endian CDR of a stamped sample with one given frame keeps its stamp and fields.

    Attributes:
        length: bytes of such a message (encapsulation header included).
        head: the bytes every such message starts with at ``head_at``: the frame's length, text and NUL.
        dtype: a record of ``sec`` (int32), ``nanosec`` (uint32) and the fields asked (float64), in order.
    """

    length: int
    head: bytes
    head_at: int
    dtype: np.dtype

    def decode(self, raws: list[bytes]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(match, stamp_ns, values)`` of messages all ``length`` bytes long: ``match`` is False where the
        encapsulation or the frame is not this layout's (those rows mean nothing); ``stamp_ns`` int64,
        ``values`` one float64 row per message. The same numbers as :func:`decoder_for`'s objects hold."""
        buf = b"".join(raws)
        matrix = np.frombuffer(buf, np.uint8).reshape(len(raws), self.length)
        head = np.frombuffer(self.head, np.uint8)
        match = (matrix[:, 0] == 0) & (matrix[:, 1] == 1)
        match &= (matrix[:, self.head_at : self.head_at + len(head)] == head).all(axis=1)
        records = np.frombuffer(buf, self.dtype)
        stamp_ns = records["sec"].astype(np.int64) * 1_000_000_000 + records["nanosec"].astype(np.int64)
        columns = [records[name] for name in self.dtype.names[2:]]  # type: ignore[index]
        values = np.column_stack(columns) if columns else np.empty((len(raws), 0))
        return match, stamp_ns, values.astype(np.float64)


def _is_double(t: Any) -> bool:
    return isinstance(t, rosidl.BasicType) and t.typename == "double"


def _double_slots(cls: type, prefix: str, out: dict[str, tuple[int, int]], skip: int = 0) -> bool:
    """Into ``out``, path -> (first float64 of the message's run, how many) of every field of ``cls`` after its
    first ``skip``, which must hold float64s only (basic, fixed arrays, nested such messages); False when not."""
    names = list(cls.get_fields_and_field_types())  # type: ignore[attr-defined]
    types = list(cls.SLOT_TYPES)  # type: ignore[attr-defined]
    for name, t in zip(names[skip:], types[skip:], strict=True):
        path = prefix + name
        count = _slot_count(out)
        if _is_double(t):
            out[path] = (count, 1)
        elif isinstance(t, rosidl.Array) and _is_double(t.value_type):
            out[path] = (count, int(t.size))
        elif isinstance(t, rosidl.NamespacedType):
            if not _double_slots(_message_class(t), path + ".", out):
                return False
        else:
            return False
    return True


def _slot_count(out: dict[str, tuple[int, int]]) -> int:
    return max((start + width for start, width in out.values()), default=0)


def stamped_layout(msg_type: type, frame_id: str, fields: tuple[str, ...]) -> StampedLayout | None:
    """The :class:`StampedLayout` of ``msg_type`` with frame ``frame_id`` and the float64 ``fields``
    (``"point.x"``, ``"linear_acceleration_covariance"``: a fixed array gives one column per element), or None
    when the type is not a Header followed by float64s only (``PointStamped``, ``Imu``), a field is not one
    of them, or the frame is empty or holds a NUL."""
    try:
        names = list(msg_type.get_fields_and_field_types())  # type: ignore[attr-defined]
        slot_types = list(msg_type.SLOT_TYPES)  # type: ignore[attr-defined]
    except AttributeError:
        return None
    if len(names) < 2 or names[0] != "header" or not isinstance(slot_types[0], rosidl.NamespacedType):
        return None
    if tuple(slot_types[0].namespaced_name()) != ("std_msgs", "msg", "Header"):
        return None
    slots: dict[str, tuple[int, int]] = {}
    if not _double_slots(msg_type, "", slots, skip=1):
        return None
    text = frame_id.encode()
    if not text or b"\x00" in text or any(f not in slots for f in fields):
        return None
    # Payload offsets (CDR aligns relative to the byte after the 4-byte encapsulation header): stamp.sec 0,
    # stamp.nanosec 4, frame length 8, its text and NUL from 12, then the float64s aligned to 8.
    after_frame = 12 + len(text) + 1
    start = 4 + after_frame + (-after_frame) % 8
    length = start + 8 * _slot_count(slots)
    formats: list[Any] = ["<i4", "<u4"]
    for f in fields:
        width = slots[f][1]
        formats.append("<f8" if width == 1 else ("<f8", (width,)))
    dtype = np.dtype(
        {
            "names": ["sec", "nanosec", *(f"v{i}" for i in range(len(fields)))],
            "formats": formats,
            "offsets": [4, 8, *(start + 8 * slots[f][0] for f in fields)],
            "itemsize": length,
        }
    )
    return StampedLayout(length, struct.pack("<I", len(text) + 1) + text + b"\x00", 12, dtype)
