"""rosbag2 input and output shared by every tool of the project.

* :func:`typestore` — the ROS 2 Jazzy typestore of ``rosbags`` with the
  project's ``terrain_msgs`` registered from the very ``.msg`` files the
  interface package installed, so that a bag written with it carries every
  message definition it uses and decodes with no project code.
* :func:`read_bag` — the messages of a bag in recorded order, deserialised
  into the rclpy message classes the live nodes receive, so that an offline
  run and a live run feed identical objects to the same adapters. It refuses
  a topic of another type than expected (:class:`TopicTypeError`) before any
  message, and skips a message whose bytes do not decode, reporting it, as
  the live nodes reject such a sample.
  :func:`bag_contents` and :func:`require_topics` list a bag's topics with
  their types and counts, for "expected these topics, found these".
* :class:`AtomicBagWriter` — writes a bag into a temporary directory next to
  the target and moves it into place only when complete: a crash or Ctrl-C
  leaves the previous complete bag or none, never a truncated one. It never
  replaces what is not a previous bag output, nor an input of the run
  (:mod:`terrain_estimation.outputs`).

Messages are serialised with rclpy (CDR, identical to what a live publisher
sends, in its canonical bytes: cut to length, padding zeroed) and stored with
rosbags; every bag written decodes with rosbags' ``AnyReader`` and with rclpy,
and the same messages always give the same bytes.
"""

from __future__ import annotations

import bisect
import functools
import importlib
import operator
import os
import re
import shutil
import socket
import struct
import sys
import uuid
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from terrain_estimation.errors import BagError

__all__ = [
    "bag_contents",
    "bag_topics",
    "BagError",
    "BagMessage",
    "BagTopic",
    "AtomicBagWriter",
    "message_class",
    "msgtype_name",
    "msgtype_of",
    "MissingTopicsError",
    "read_bag",
    "read_bag_raw",
    "read_bag_raw_batches",
    "RawTally",
    "remove_stale_partials",
    "require_topics",
    "StalePartialWarning",
    "terrain_msgs_definitions",
    "TopicTypeError",
    "typestore",
    "UndecodableHandler",
    "UndecodableMessagesWarning",
]

TERRAIN_MSGS = "terrain_msgs"


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


class TopicTypeError(BagError):
    """A topic recorded with another message type than the one expected."""

    def __init__(self, bag: Path, topic: str, expected: str, found: str) -> None:
        super().__init__(f"bag {str(bag)!r}: topic {topic} has type {found}, expected {expected}")
        self.topic, self.expected, self.found = topic, expected, found


class MissingTopicsError(BagError):
    """A bag without messages on topics a run needs; the message lists what was expected and found."""


class UndecodableMessagesWarning(UserWarning):
    """Messages of a bag skipped by :func:`read_bag` because their bytes do not decode."""


#: ``on_undecodable(topic, log_time_ns, exception)``: told of each message read_bag skips.
UndecodableHandler = Callable[[str, int, Exception], None]


@dataclass(frozen=True)
class BagTopic:
    """A topic of a bag as its metadata lists it: type and message count."""

    topic: str
    msgtype: str
    count: int

    def __str__(self) -> str:
        return f"{self.topic} ({self.msgtype}, {self.count} messages)"


def _bag_dir(path: str | os.PathLike[str]) -> Path:
    """The bag directory of ``path`` (a bag directory or its storage file); BagError when missing."""
    bag = Path(path)
    if bag.is_file():
        bag = bag.parent
    if not bag.exists():
        raise BagError(f"bag {str(bag)!r} does not exist")
    return bag


def bag_contents(path: str | os.PathLike[str]) -> dict[str, BagTopic]:
    """Every topic of a rosbag2 bag with its type and message count (from the metadata; nothing decoded).

    A topic recorded under two types lists both, joined by ``" | "``.
    """
    bag = _bag_dir(path)
    try:
        with Reader(bag) as reader:
            connections = list(reader.connections)
    except Exception as exc:  # rosbags' own errors: name the bag
        raise BagError(f"bag {str(bag)!r} is unreadable: {type(exc).__name__}: {exc}") from exc
    types: dict[str, set[str]] = {}
    counts: dict[str, int] = {}
    for conn in connections:
        types.setdefault(conn.topic, set()).add(conn.msgtype)
        counts[conn.topic] = counts.get(conn.topic, 0) + conn.msgcount
    return {t: BagTopic(t, " | ".join(sorted(types[t])), counts[t]) for t in sorted(types)}


def bag_topics(path: str | os.PathLike[str]) -> set[str]:
    """Topics of a rosbag2 bag that hold at least one message (from the metadata; nothing decoded)."""
    return {t.topic for t in bag_contents(path).values() if t.count > 0}


def require_topics(path: str | os.PathLike[str], expected: Mapping[str, str]) -> dict[str, BagTopic]:
    """Check that a bag has messages on every ``expected`` topic, of the expected type; return its contents.

    Args:
        path: the bag.
        expected: absolute topic -> ``pkg/msg/Name`` the run needs.

    Raises:
        TopicTypeError: a topic of another type (named with both types).
        MissingTopicsError: topics without messages; the message lists the
            expected topics and every topic the bag has ("expected ...,
            found ...").
    """
    bag = _bag_dir(path)
    contents = bag_contents(bag)
    for topic, msgtype in expected.items():
        found = contents.get(topic)
        if found is not None and found.msgtype != msgtype:
            raise TopicTypeError(bag, topic, msgtype, found.msgtype)
    missing = [t for t in expected if t not in contents or contents[t].count == 0]
    if missing:
        wanted = "; ".join(f"{t} ({expected[t]})" for t in expected)
        have = "; ".join(str(t) for t in contents.values()) or "no topics"
        raise MissingTopicsError(
            f"bag {str(bag)!r} has no messages on {', '.join(missing)}: expected {wanted}; found {have}"
        )
    return contents


def read_bag(
    path: str | os.PathLike[str],
    topics: Iterable[str] | None = None,
    *,
    types: Mapping[str, str] | None = None,
    on_undecodable: UndecodableHandler | None = None,
) -> Iterator[BagMessage]:
    """Yield the messages of a rosbag2 bag (mcap or sqlite3) in recorded order.

    Args:
        path: the bag directory (or its ``.mcap``/``.db3`` file's directory).
        topics: absolute topic names to read; None reads all.
        types: absolute topic -> expected ``pkg/msg/Name``; a topic of the bag
            recorded with another type raises :class:`TopicTypeError` before
            any message is read (topics not in the bag are not checked: see
            :func:`require_topics`).
        on_undecodable: called as ``on_undecodable(topic, log_time_ns, exc)``
            for each message whose bytes do not decode; the message is skipped
            and reading goes on, as the live nodes reject such a sample. With
            None, one :class:`UndecodableMessagesWarning` at the end says how
            many were skipped on which topics.

    Raises:
        TopicTypeError: a topic of ``types`` has another type in the bag.
        BagError: the bag is missing, unreadable, truncated or corrupt (its
            storage, not one message's bytes); the message names the bag, the
            topic and how many messages were read.
    """
    tally = RawTally()
    for conn, timestamp, raw, decode in read_bag_raw(path, topics, types=types, tally=tally):
        try:
            msg = decode(raw)
        except Exception as exc:  # one message's bytes: reject it and go on, as the nodes do
            tally.undecodable(conn.topic, exc)
            if on_undecodable is not None:
                on_undecodable(conn.topic, timestamp, exc)
            continue
        yield BagMessage(conn.topic, conn.msgtype, timestamp, msg)
    if tally.skipped and on_undecodable is None:
        warnings.warn(
            f"bag {str(_bag_dir(path))!r}: skipped {sum(tally.skipped.values())} message(s) whose bytes do not "
            f"decode{_skipped_text(tally.skipped)}; first error: {type(tally.first_error).__name__}: "
            f"{tally.first_error}",
            UndecodableMessagesWarning,
            stacklevel=2,
        )


@dataclass
class RawTally:
    """The messages :func:`read_bag_raw` handed out (``read``) and those its reader could not decode
    (``skipped``, by topic, kept by the reader), for the errors the stream raises ("unreadable after N
    messages")."""

    read: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    first_error: Exception | None = None

    @property
    def count(self) -> int:
        """Messages read and not skipped."""
        return self.read - sum(self.skipped.values())

    def undecodable(self, topic: str, exc: Exception) -> None:
        self.skipped[topic] = self.skipped.get(topic, 0) + 1
        self.first_error = self.first_error or exc


RawItem = tuple[Any, int, bytes, Callable[[bytes], Any]]


def read_bag_raw(
    path: str | os.PathLike[str],
    topics: Iterable[str] | None = None,
    *,
    types: Mapping[str, str] | None = None,
    tally: RawTally | None = None,
) -> Iterator[RawItem]:
    """:func:`read_bag` before decoding: ``(connection, log time ns, bytes, decoder)`` in recorded order.

    The caller decodes (``decoder(bytes)``, the nodes' decoder of the topic's class, or in bulk) and records
    in ``tally`` (:meth:`RawTally.undecodable`) the messages it could not; the errors are :func:`read_bag`'s.
    """
    for batch in read_bag_raw_batches(path, topics, types=types, tally=tally):
        yield from batch


def read_bag_raw_batches(
    path: str | os.PathLike[str],
    topics: Iterable[str] | None = None,
    *,
    types: Mapping[str, str] | None = None,
    tally: RawTally | None = None,
) -> Iterator[list[RawItem]]:
    """:func:`read_bag_raw`'s messages in lists, in the same order, read (and counted in ``tally``) a list at a
    time: an MCAP bag's messages up to the next chunk's first log time (:func:`_fast_batches`), else one by
    one. A storage error is raised where :func:`read_bag_raw` raises it: after the same messages."""
    from rclpy.serialization import deserialize_message  # adapters layer: rclpy is fine here

    from terrain_estimation.ros.cdr import decoder_for

    bag = _bag_dir(path)
    wanted = set(topics) if topics is not None else None
    tally = tally if tally is not None else RawTally()
    topic = "<none>"
    try:
        with Reader(bag) as reader:
            for conn in reader.connections:
                expected = (types or {}).get(conn.topic)
                if expected is not None and conn.msgtype != expected:
                    raise TopicTypeError(bag, conn.topic, expected, conn.msgtype)
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
            fast = _fast_batches(reader, connections) if _FAST_READ else None
            batches = fast or ([item] for item in reader.messages(connections=connections))
            for batch in batches:
                if not batch:
                    continue
                items = [(conn, timestamp, bytes(raw), decoders[conn.id]) for conn, timestamp, raw in batch]
                topic = items[-1][0].topic
                tally.read += len(items)
                yield items
            # rosbags stops without a word at a chunk it cannot parse: hold the count to the metadata's
            listed = sum(c.msgcount for c in connections)
            seen = tally.read
            if seen < listed:
                raise BagError(
                    f"bag {str(bag)!r} is unreadable after {seen} of the {listed} messages its metadata lists on "
                    f"the topics read{_skipped_text(tally.skipped)} (last topic {topic}): the storage file is "
                    "truncated or corrupt"
                )
    except BagError:
        raise
    except Exception as exc:  # rosbags/storage errors: name what was read
        raise BagError(
            f"bag {str(bag)!r} is unreadable after {tally.count} messages{_skipped_text(tally.skipped)} "
            f"(last topic {topic}): {type(exc).__name__}: {exc}"
        ) from exc


def _fast_batches(reader: Reader, connections: list[Any]) -> Iterator[list[tuple[Any, int, bytes]]] | None:
    """``reader.messages(connections=connections)`` for a bag of one chunked MCAP file (what this project
    writes), in lists and in fewer Python steps per message; None for any other bag (or rosbags' internals not
    as known).

    rosbags 0.11 reads such a bag through ``Reader`` -> ``DirectoryReader`` -> ``McapReader``: per chunk, a
    generator (``msgsrc``) that checks and decompresses the chunk, parses its records one ``BytesIO`` at a
    time and yields them sorted by log time, after a first item at the chunk's start time, the chunks merged
    by ``heapq.merge``. This does the same with the same checks, the same order and the same errors, parsing
    the records in place (:func:`_chunk_messages`); the directory layer's connection matching is its own,
    copied. A chunk is read once every message before its start time has been handed out (where the merge
    reads it), and its messages merged into those not yet handed out by (log time, chunk offset), the merge's
    order (each chunk's offset differs; within a chunk, its own order).
    """
    if not _rosbags_internals_known():
        return None  # another rosbags: its own loop, which is what this copies
    from rosbags.rosbag2.reader import DirectoryReader
    from rosbags.rosbag2.storage_mcap import McapReader

    directory = getattr(reader, "storage", None)
    if type(directory) is not DirectoryReader or len(directory.storages) != 1:
        return None
    mcap = directory.storages[0]
    if type(mcap) is not McapReader or not mcap.chunks or directory.metadata.compression_mode == "message":
        return None
    connmap = {}
    for x in mcap.connections:
        conn = next(
            (
                y
                for y in connections
                if y.topic == x.topic
                and y.msgtype == x.msgtype
                and y.ext == x.ext
                and (not x.digest or not y.digest or y.digest == x.digest)
            ),
            None,
        )
        if conn is not None:
            connmap[x.id] = conn
    channel_map = {x.id: x for x in mcap.connections if x.id in connmap}
    chunks = [chunk for chunk in mcap.chunks if any(chunk.channel_count.get(cid, 0) for cid in channel_map)]
    # The merge's order of the chunks' first items (start time, 0, None, None): by start time, ties in list order.
    order = sorted(range(len(chunks)), key=lambda i: chunks[i].message_start_time)
    return _merged_batches([chunks[i] for i in order], channel_map, connmap, mcap.bio)


_TIME = operator.itemgetter(0)
_TIME_AND_OFFSET = operator.itemgetter(0, 1)


def _merged_batches(
    chunks: Sequence[Any], channel_map: Mapping[int, Any], connmap: Mapping[int, Any], bio: Any
) -> Iterator[list[tuple[Any, int, bytes]]]:
    """The messages of ``chunks`` (in start-time order) in ``heapq.merge``'s order (:func:`_fast_batches`)."""
    waiting: list[tuple[int, int, Any, bytes]] = []  # read, not handed out: sorted by (log time, offset)
    for chunk in chunks:
        cut = bisect.bisect_left(waiting, chunk.message_start_time, key=_TIME)
        if cut:  # every later message is at or after this chunk's start
            yield [(connmap[c.id], t, data) for t, _, c, data in waiting[:cut]]
            del waiting[:cut]
        messages = _chunk_messages(chunk, channel_map, bio)
        if waiting and messages:  # overlapping chunks: merged where they overlap
            overlap = bisect.bisect_right(messages, waiting[-1][0], key=_TIME)
            waiting = sorted(waiting + messages[:overlap], key=_TIME_AND_OFFSET) + messages[overlap:]
        else:
            waiting.extend(messages)
    if waiting:
        yield [(connmap[c.id], t, data) for t, _, c, data in waiting]


#: The rosbags releases whose reader internals :func:`_fast_batches` copies (constraints.txt pins 0.11.9).
_KNOWN_ROSBAGS = ("0.11.",)


@cache
def _rosbags_internals_known() -> bool:
    """True when the installed rosbags is a release :func:`_fast_batches` was checked against (the names it
    reaches into are private); any other release reads through rosbags' own loop."""
    import importlib.metadata

    try:
        version = importlib.metadata.version("rosbags")
        from rosbags.rosbag2.reader import DirectoryReader  # noqa: F401
        from rosbags.rosbag2.storage_mcap import McapReader, decompress, read_exact  # noqa: F401
    except (ImportError, importlib.metadata.PackageNotFoundError):  # pragma: no cover - another rosbags
        return False
    return version.startswith(_KNOWN_ROSBAGS)


#: :func:`read_bag_raw` reads MCAP bags through :func:`_fast_batches` (False: through rosbags' own loop, as
#: before; the benchmark's previous path).
_FAST_READ = True
_RECORD_SIZE = struct.Struct("<Q")
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time


def _chunk_messages(chunk: Any, channel_map: Mapping[int, Any], bio: Any) -> list[tuple[int, int, Any, bytes]]:
    """rosbags' ``storage_mcap.msgsrc`` for a whole chunk (no time range), its records parsed in place: its
    messages sorted by log time (stable), without the first item at the chunk's start time."""
    from rosbags.rosbag2.errors import ReaderError
    from rosbags.rosbag2.storage_mcap import decompress, read_exact

    # rosbags' Msg named tuples (timestamp, offset, connection, data) as plain tuples: they compare alike.
    bio.seek(chunk.chunk_start_offset + 9 + 24)
    (crc,) = struct.unpack("<I", read_exact(bio, 4))
    bio.seek(chunk.chunk_start_offset + 9 + 40 + len(chunk.compression))
    data = decompress(read_exact(bio, chunk.compressed_size), chunk.compression, chunk.uncompressed_size, crc)
    start, stop = chunk.message_start_time, chunk.message_end_time + 1
    offset = chunk.chunk_start_offset
    size_total = chunk.uncompressed_size
    messages = []
    pos = 0
    while pos < size_total:
        op = data[pos]
        if pos + 9 > size_total:
            got = size_total - pos - 1
            raise ReaderError(f"Truncated record at offset {pos + 1}: expected 8 bytes, got {got}.")
        (size,) = _RECORD_SIZE.unpack_from(data, pos + 1)
        body = pos + 9
        pos = body + size
        if op != 0x05:
            continue  # (rosbags skips it by seeking: past the end it stops there, unchecked)
        if pos > size_total:
            raise ReaderError(f"Truncated record at offset {body}: expected {size} bytes, got {size_total - body}.")
        if size < 22:
            raise struct.error("unpack requires a buffer of 22 bytes")
        channel_id, _, log_time, _ = _MESSAGE_HEAD.unpack_from(data, body)
        if start <= log_time < stop and channel_id in channel_map:
            messages.append((log_time, offset, channel_map[channel_id], data[body + 22 : pos]))
    messages.sort(key=_TIME)
    return messages


def _skipped_text(skipped: Mapping[str, int]) -> str:
    if not skipped:
        return ""
    return " (undecodable, skipped: " + ", ".join(f"{t} {n}" for t, n in sorted(skipped.items())) + ")"


# Scratch directories of a writer: ".<name>.partial-<pid>@<host>-<hex>" while writing,
# ".<name>.old-<pid>@<host>-<hex>" for the bag it replaces, for the instant of the swap.
_HOST = re.sub(r"[^A-Za-z0-9.-]", "_", socket.gethostname()) or "unknown"


def _scratch_path(target: Path, what: str) -> Path:
    return target.with_name(f".{target.name}.{what}-{os.getpid()}@{_HOST}-{uuid.uuid4().hex[:8]}")


def _process_alive(pid: int) -> bool:
    """Whether process ``pid`` of this host still runs (a zombie does not; unsure counts as running)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's process
    try:  # Linux: a killed process its parent has not reaped yet is a zombie ("Z")
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return True


def remove_stale_partials(target: str | os.PathLike[str]) -> tuple[list[Path], list[str]]:
    """Remove what killed writers of ``target`` left: ``(removed, kept)``, ``kept`` as reasons.

    Only siblings named exactly ``.<name>.partial-<pid>@<host>-<hex>`` or
    ``.<name>.old-<pid>@<host>-<hex>`` whose process on this host is dead
    and that hold only bag files are removed. Those of another host or of a
    running process, or holding anything else, are kept and named in ``kept``.
    """
    from terrain_estimation.outputs import is_bag_directory

    path = Path(target)
    pattern = re.compile(rf"\.{re.escape(path.name)}\.(?:partial|old)-(\d+)@([A-Za-z0-9._-]+)-[0-9a-f]{{8}}")
    removed: list[Path] = []
    kept: list[str] = []
    if not path.parent.is_dir():
        return removed, kept
    for entry in sorted(path.parent.iterdir()):
        match = pattern.fullmatch(entry.name)
        if match is None or not entry.is_dir() or entry.is_symlink():
            continue
        pid, host = int(match.group(1)), match.group(2)
        if host != _HOST:
            kept.append(f"{entry} (written on host {host}: cannot tell whether its writer still runs)")
        elif _process_alive(pid):
            kept.append(f"{entry} (its writer, process {pid}, is still running)")
        elif not (is_bag_directory(entry, require_metadata=False) or not any(entry.iterdir())):
            kept.append(f"{entry} (holds files other than a bag's)")
        else:
            try:
                shutil.rmtree(entry)
                removed.append(entry)
            except OSError as exc:
                kept.append(f"{entry} ({exc})")
    return removed, kept


class AtomicBagWriter:
    """A rosbag2 (MCAP) writer that only ever leaves complete bags behind, and destroys nothing.

    Use as a context manager. Messages are rclpy objects; connections are
    added on first use of a topic. The bag is written into a hidden sibling
    ``.NAME.partial-<pid>@<host>-<hex>`` and moved to ``path`` on a clean
    exit; on an exception or Ctrl-C the partial bag is deleted and ``path``
    is left as it was. A partial bag left by a killed writer (SIGKILL, power
    loss) is removed by the next writer of the same path once its process is
    dead (:func:`remove_stale_partials`); any it cannot remove is named in a
    :class:`StalePartialWarning`.

    Args:
        path: the output bag directory.
        overwrite: the user's ``--overwrite``: a previous bag at ``path`` (a
            rosbag2 directory and nothing else) may be replaced. Without it
            an existing ``path`` raises
            :class:`terrain_estimation.outputs.OutputExistsError` at
            construction; a directory that is not a bag, a file or a symlink
            is refused even with it.
        inputs: every path the run reads; an output that is, is inside, or
            contains one raises
            :class:`terrain_estimation.outputs.OutputIsInputError`.

    Messages are serialised by rclpy and cut to their exact CDR length (see
    :meth:`write`), so the bag decodes with rosbags and with rclpy.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        overwrite: bool = False,
        inputs: Iterable[str | os.PathLike[str]] = (),
    ) -> None:
        from terrain_estimation.outputs import check_output_path

        self.path = Path(path)
        self.overwrite = overwrite
        self.inputs = tuple(inputs)
        check_output_path(self.path, overwrite=overwrite, inputs=self.inputs)
        self._tmp = _scratch_path(self.path, "partial")
        self._writer: Writer | None = None
        self._connections: dict[str, Any] = {}
        self.count = 0
        #: Stale partial bags of ``path`` removed on entering.
        self.removed_partials: list[Path] = []

    def __enter__(self) -> AtomicBagWriter:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.removed_partials, kept = remove_stale_partials(self.path)
        if kept:
            warnings.warn(
                f"partial bag(s) of {str(self.path)!r} left in place: " + "; ".join(kept),
                StalePartialWarning,
                stacklevel=2,
            )
        self._writer = Writer(self._tmp, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        return self

    def write(self, topic: str, msg: Any, log_time_ns: int) -> None:
        """Append ``msg`` (an rclpy message) on ``topic`` at ``log_time_ns``.

        rclpy's ``serialize_message`` (rmw_fastrtps, Jazzy) returns a buffer
        longer than the CDR it holds whenever the message has an empty
        sequence, the tail being uninitialised memory; rosbags then refuses
        the message ("CDR message size mismatch"). rclpy also leaves the
        alignment padding uninitialised. The bytes written are the canonical
        ones (:func:`_canonical_cdr`): cut to the length rosbags' walk of the
        definition finds, then read and written again by rosbags' serialiser.
        """
        from rclpy.serialization import serialize_message

        assert self._writer is not None, "use AtomicBagWriter as a context manager"
        conn = self._connections.get(topic)
        if conn is None:
            msgtype = msgtype_of(msg)
            conn = self._writer.add_connection(topic, msgtype, typestore=typestore())
            self._connections[topic] = conn
        self._writer.write(conn, int(log_time_ns), _canonical_cdr(serialize_message(msg), conn.msgtype))
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
            # rosbags names the storage file after the directory: rename it too so
            # the final bag is self-consistent (<name>/<name>.mcap + metadata.yaml).
            final_name = self.path.name
            mcap = self._tmp / f"{self._tmp.name}.mcap"
            if mcap.exists():
                mcap.rename(self._tmp / f"{final_name}.mcap")
                meta = self._tmp / "metadata.yaml"
                meta.write_text(meta.read_text().replace(f"{self._tmp.name}.mcap", f"{final_name}.mcap"))
            # Once more now: something may have appeared at the path while writing.
            from terrain_estimation.outputs import check_output_path

            check_output_path(self.path, overwrite=self.overwrite, inputs=self.inputs)
        except BaseException:
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise
        old = _scratch_path(self.path, "old")
        if self.path.exists():
            self.path.rename(old)
        self._tmp.rename(self.path)
        shutil.rmtree(old, ignore_errors=True)


class StalePartialWarning(UserWarning):
    """Partial bags of a killed writer that :class:`AtomicBagWriter` could not remove."""


def _canonical_cdr(raw: bytes, msgtype: str) -> bytes:
    """rclpy's CDR of a message as rosbags writes it: cut to its length, padding zeroed.

    rclpy leaves the alignment padding (and, after an empty sequence, a tail) uninitialised:
    whatever the process's memory held ends up in the bag, and the same messages give
    other bytes on every run. Read back and written again by rosbags' own serialiser, the
    bytes are a function of the values alone (measured: 15 µs per Imu or JointState).
    """
    store = typestore()
    return bytes(store.serialize_cdr(store.deserialize_cdr(raw[: 4 + _cdr_length(raw, msgtype)], msgtype), msgtype))


def _cdr_length(raw: bytes, msgtype: str) -> int:
    """Length of the CDR body of ``raw`` (after its 4-byte header) as rosbags walks ``msgtype``.

    Raises:
        BagError: the bytes are shorter than the type needs, or not little-endian CDR.
    """
    if raw[:2] != b"\x00\x01":
        raise BagError(f"{msgtype}: rclpy serialised {raw[:4].hex()!r}, not little-endian CDR")
    store = typestore()
    try:
        end, _ = store.get_msgdef(msgtype).getsize_cdr_to_ros1(memoryview(raw)[4:], 0, None, 0, store)
    except Exception as exc:
        raise BagError(f"{msgtype}: rclpy's bytes do not walk as rosbags' definition: {exc}") from exc
    if 4 + end > len(raw):
        raise BagError(f"{msgtype}: rclpy's {len(raw)} bytes are shorter than the CDR rosbags reads ({4 + end})")
    return int(end)


def msgtype_name(cls: type) -> str:
    """``pkg/msg/Name`` of an rclpy message class (``sensor_msgs.msg._imu.Imu`` -> ``sensor_msgs/msg/Imu``)."""
    return f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"


def msgtype_of(msg: Any) -> str:
    """``pkg/msg/Name`` of an rclpy message object."""
    return msgtype_name(type(msg))
