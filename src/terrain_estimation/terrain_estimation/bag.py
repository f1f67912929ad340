"""rosbag2 input and output shared by every tool of the project.

* :func:`typestore` — the ROS 2 Jazzy typestore of ``rosbags`` with the
  project's ``terrain_msgs`` registered from the very ``.msg`` files the
  interface package installed, so that a bag written with it carries every
  message definition it uses and decodes with no project code.
* :func:`read_bag` — the messages of a bag in recorded order, deserialised
  into the rclpy message classes the live nodes receive, so that an offline
  run and a live run feed identical objects to the same adapters.
* :class:`AtomicBagWriter` — writes a bag into a temporary directory next to
  the target and moves it into place only when complete: a crash or Ctrl-C
  leaves the previous complete bag or none, never a truncated one.

Messages are serialised with rclpy (CDR, identical to what a live publisher
sends) and stored with rosbags.
"""

from __future__ import annotations

import functools
import importlib
import os
import shutil
import sys
import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

__all__ = [
    "bag_topics",
    "BagError",
    "BagMessage",
    "AtomicBagWriter",
    "message_class",
    "read_bag",
    "terrain_msgs_definitions",
    "typestore",
]

TERRAIN_MSGS = "terrain_msgs"


class BagError(RuntimeError):
    """A bag that cannot be read or written; the message says what and where."""


def _share_dirs() -> list[Path]:
    """Prefixes to search for installed ROS packages, ament's order first."""
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    prefixes.append(sys.prefix)  # the ROS wheels install into the venv prefix
    return [Path(p) / "share" for p in prefixes]


def terrain_msgs_definitions() -> dict[str, str]:
    """``{"terrain_msgs/msg/Name": msg text}`` from the installed interface package.

    Raises:
        BagError: when terrain_msgs is not installed (run ``make setup``).
    """
    for share in _share_dirs():
        msg_dir = share / TERRAIN_MSGS / "msg"
        files = sorted(msg_dir.glob("*.msg"))
        if files:
            return {f"{TERRAIN_MSGS}/msg/{f.stem}": f.read_text() for f in files}
    searched = ", ".join(str(s) for s in _share_dirs())
    raise BagError(f"terrain_msgs .msg files not found under {searched}; run `make setup`")


@cache
def typestore() -> Typestore:
    """ROS 2 Jazzy typestore plus terrain_msgs (cached; do not mutate)."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    for name, text in terrain_msgs_definitions().items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def message_class(msgtype: str) -> type:
    """The rclpy message class of ``pkg/msg/Name``.

    Raises:
        BagError: when the package is not installed or has no such message.
    """
    try:
        package, kind, name = msgtype.split("/")
    except ValueError:
        raise BagError(f"message type {msgtype!r} is not of the form pkg/msg/Name") from None
    try:
        module = importlib.import_module(f"{package}.{kind}")
        return getattr(module, name)
    except (ImportError, AttributeError) as exc:
        raise BagError(f"message type {msgtype!r} is not installed: {exc}") from exc


@dataclass(frozen=True)
class BagMessage:
    """One message of a bag: topic, type, log time (ns) and the rclpy object."""

    topic: str
    msgtype: str
    log_time_ns: int
    msg: Any


def bag_topics(path: str | os.PathLike[str]) -> set[str]:
    """Topics of a rosbag2 bag that hold at least one message (from the metadata; nothing decoded)."""
    bag = Path(path)
    if bag.is_file():
        bag = bag.parent
    if not bag.exists():
        raise BagError(f"bag {str(bag)!r} does not exist")
    try:
        with Reader(bag) as reader:
            return {c.topic for c in reader.connections if c.msgcount > 0}
    except Exception as exc:  # rosbags' own errors: name the bag
        raise BagError(f"bag {str(bag)!r} is unreadable: {type(exc).__name__}: {exc}") from exc


def read_bag(path: str | os.PathLike[str], topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """Yield the messages of a rosbag2 bag (mcap or sqlite3) in recorded order.

    Args:
        path: the bag directory (or its ``.mcap``/``.db3`` file's directory).
        topics: absolute topic names to read; None reads all.

    Raises:
        BagError: the bag is missing, unreadable, truncated or corrupt; the
            message names the bag, the topic and how many messages were read.
    """
    from rclpy.serialization import deserialize_message  # adapters layer: rclpy is fine here

    from terrain_estimation.ros.cdr import decoder_for

    bag = Path(path)
    if bag.is_file():
        bag = bag.parent
    if not bag.exists():
        raise BagError(f"bag {str(bag)!r} does not exist")
    wanted = set(topics) if topics is not None else None
    count = 0
    topic = "<none>"
    try:
        with Reader(bag) as reader:
            connections = [c for c in reader.connections if wanted is None or c.topic in wanted]
            # Each topic's decoder: the nodes' (ros/cdr.py, the same objects as rclpy's), else rclpy's.
            decoders: dict[int, Callable[[bytes], Any]] = {}
            for conn in connections:
                try:
                    cls = message_class(conn.msgtype)
                except BagError:
                    continue  # a type we do not use: skip its topic
                decoders[conn.id] = decoder_for(cls) or functools.partial(deserialize_message, message_type=cls)
            connections = [c for c in connections if c.id in decoders]
            if not connections:
                return  # rosbags reads every topic when given no connections
            for conn, timestamp, raw in reader.messages(connections=connections):
                topic = conn.topic
                msg = decoders[conn.id](bytes(raw))
                count += 1
                yield BagMessage(conn.topic, conn.msgtype, timestamp, msg)
    except BagError:
        raise
    except Exception as exc:  # rosbags/storage errors: name what was read
        raise BagError(
            f"bag {str(bag)!r} is unreadable after {count} messages (last topic {topic}): {type(exc).__name__}: {exc}"
        ) from exc


class AtomicBagWriter:
    """A rosbag2 (MCAP) writer that only ever leaves complete bags behind.

    Use as a context manager. Messages are rclpy objects; connections are
    added on first use of a topic. On a clean exit the bag is moved to
    ``path`` (replacing a previous bag there); on an exception or Ctrl-C the
    partial bag is deleted and ``path`` is left as it was.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._tmp = self.path.with_name(f".{self.path.name}.partial-{uuid.uuid4().hex[:8]}")
        self._writer: Writer | None = None
        self._connections: dict[str, Any] = {}
        self.count = 0

    def __enter__(self) -> AtomicBagWriter:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._writer = Writer(self._tmp, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        return self

    def write(self, topic: str, msg: Any, log_time_ns: int) -> None:
        """Append ``msg`` (an rclpy message) on ``topic`` at ``log_time_ns``."""
        from rclpy.serialization import serialize_message

        assert self._writer is not None, "use AtomicBagWriter as a context manager"
        conn = self._connections.get(topic)
        if conn is None:
            msgtype = msgtype_of(msg)
            conn = self._writer.add_connection(topic, msgtype, typestore=typestore())
            self._connections[topic] = conn
        self._writer.write(conn, int(log_time_ns), serialize_message(msg))
        self.count += 1

    def write_all(self, messages: Sequence[tuple[str, Any, int]]) -> None:
        for topic, msg, t_ns in messages:
            self.write(topic, msg, t_ns)

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        writer, self._writer = self._writer, None
        if exc_type is not None:
            # The partial bag is thrown away: no close(), which would first write the index of
            # every message so far (slow on a long run, and after an interrupt inside the
            # writer its state may be half-updated). The open file goes with the writer.
            del writer
            shutil.rmtree(self._tmp, ignore_errors=True)
            return
        try:
            if writer is not None:
                writer.close()
        except BaseException:
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise
        # rosbags names the storage file after the directory: rename it too so
        # the final bag is self-consistent (<name>/<name>.mcap + metadata.yaml).
        final_name = self.path.name
        mcap = self._tmp / f"{self._tmp.name}.mcap"
        if mcap.exists():
            mcap.rename(self._tmp / f"{final_name}.mcap")
            meta = self._tmp / "metadata.yaml"
            meta.write_text(meta.read_text().replace(f"{self._tmp.name}.mcap", f"{final_name}.mcap"))
        old = self.path.with_name(f".{final_name}.old-{uuid.uuid4().hex[:8]}")
        if self.path.exists():
            self.path.rename(old)
        self._tmp.rename(self.path)
        shutil.rmtree(old, ignore_errors=True)


def msgtype_of(msg: Any) -> str:
    """``pkg/msg/Name`` of an rclpy message object."""
    module = type(msg).__module__  # e.g. sensor_msgs.msg._imu
    package = module.split(".")[0]
    return f"{package}/msg/{type(msg).__name__}"
