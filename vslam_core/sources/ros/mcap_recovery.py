"""The readable start of an MCAP file that was cut short (the recorder killed, the disk full, a copy interrupted).

An MCAP file ends with its summary (the index of every chunk) and a footer; a file without them is refused by
``rosbags``, whose reader starts from the footer. The data section before the cut is still a valid stream of
records, so `recover_mcap` reads it front to back with the ``mcap`` package's non-seeking
``mcap.stream_reader.StreamReader`` (chunks decompressed on the way) until a record is incomplete: the messages of
every complete record (complete chunk) are recovered, those of the record the file stops in are lost.

`RecoveredMcap.open` returns a reader with the part of ``rosbags.highlevel.AnyReader``'s interface that
`RosbagSource` uses (``topics``, ``connections``, ``messages``, ``deserialize``, ``close``); each ``messages`` call
streams the file again (never held in memory) and stops at the cut. Message types come from the file's schemas
(``ros2msg`` / ``ros2idl``), or ROS 2 Humble's when it has none.
"""

from __future__ import annotations

from collections.abc import Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from vslam_core.errors import SourceError

MCAP_MAGIC = b"\x89MCAP0\r\n"


def is_cut_short(path: Path) -> bool:
    """True for a file that starts as an MCAP file but does not end as one (no footer magic)."""
    try:
        with path.open("rb") as stream:
            head = stream.read(len(MCAP_MAGIC))
            size = stream.seek(0, 2)
            if head != MCAP_MAGIC:
                return False
            if size < 2 * len(MCAP_MAGIC):
                return True
            stream.seek(size - len(MCAP_MAGIC))
            return stream.read() != MCAP_MAGIC
    except OSError:
        return False


@dataclass(frozen=True)
class Connection:
    """One channel of the file, as `RosbagSource` sees a connection (``topic``, ``msgtype``)."""

    id: int
    topic: str
    msgtype: str


@dataclass(frozen=True)
class TopicInfo:
    msgtype: str


@dataclass
class RecoveredMcap:
    """What `recover_mcap` found: the channels, how many messages (per topic) precede the cut, where the file stops
    (`stopped_at`: the byte offset of the first incomplete record, `size`: the file's size) and the last message's
    log time (ns)."""

    path: Path
    connections: dict[int, Connection]
    schemas: dict[str, tuple[str, str]]  # msgtype -> (encoding, definition)
    messages: int
    per_topic: dict[str, int]
    stopped_at: int
    size: int
    last_log_time: int | None
    _typestore: Any = field(default=None, repr=False)

    def open(self) -> RecoveredReader:
        """A reader over the recovered messages (see the module docstring)."""
        if self._typestore is None:
            self._typestore = _typestore(self.schemas, self.path)
        return RecoveredReader(self, self._typestore)

    def note(self, topic: str) -> str:
        """One line for the user: what was recovered and where the file stops."""
        when = "" if self.last_log_time is None else f", the last at log time {_format_ns(self.last_log_time)}"
        return (f"{self.path}: the log is cut short (no MCAP summary: the recorder was killed?); recovered "
                f"{self.messages} messages ({self.per_topic.get(topic, 0)} of {topic}{when}) from the "
                f"{self.stopped_at} bytes before the cut (the file has {self.size}); running on them")


class RecoveredReader:
    """`AnyReader`'s interface over the recovered messages of a cut-short MCAP file."""

    def __init__(self, recovered: RecoveredMcap, typestore: Any):
        self._recovered = recovered
        self._typestore = typestore
        self.connections = list(recovered.connections.values())
        self.topics = {c.topic: TopicInfo(c.msgtype) for c in self.connections}
        self._streams: list[BinaryIO] = []

    def messages(self, connections: Collection[Connection] = (), start: int | None = None,
                 stop: int | None = None) -> Iterator[tuple[Connection, int, bytes]]:
        """(connection, log time ns, raw CDR bytes) of the recovered messages of `connections` (all when empty)
        with ``start <= log time < stop``, in file order."""
        from mcap.records import Message

        wanted = {c.id for c in connections} or set(self._recovered.connections)
        for record in self._records():
            if not isinstance(record, Message) or record.channel_id not in wanted:
                continue
            if (start is not None and record.log_time < start) or (stop is not None and record.log_time >= stop):
                continue
            yield self._recovered.connections[record.channel_id], record.log_time, bytes(record.data)

    def _records(self) -> Iterator[Any]:
        stream = self._recovered.path.open("rb")
        self._streams.append(stream)
        try:
            yield from _records_before_cut(stream, self._recovered.stopped_at)
        finally:
            stream.close()
            self._streams.remove(stream)

    def deserialize(self, raw: bytes, msgtype: str) -> object:
        return self._typestore.deserialize_cdr(raw, msgtype)

    def close(self) -> None:
        for stream in list(self._streams):
            stream.close()
        self._streams.clear()


def _records_before_cut(stream: BinaryIO, stop_at: int | None) -> Iterator[Any]:
    """The records of an MCAP stream (chunks opened) that end before byte `stop_at` (None: until one is
    incomplete); a record the file stops in ends the stream quietly."""
    from mcap.stream_reader import StreamReader

    reader = StreamReader(stream, skip_magic=False, emit_chunks=False)
    records = reader.records
    while True:
        try:
            record = next(records)
        except StopIteration:
            return
        except Exception:  # noqa: BLE001 - the incomplete (or garbled) record at the cut: the recovery ends here
            return
        if stop_at is not None and stream.tell() > stop_at:
            return
        yield record


def recover_mcap(path: Path) -> RecoveredMcap:
    """Read the complete records of a cut-short MCAP file front to back (see the module docstring); `SourceError`
    when not a single message can be recovered."""
    from mcap.records import Channel, Message, Schema

    schemas: dict[int, Schema] = {}
    connections: dict[int, Connection] = {}
    definitions: dict[str, tuple[str, str]] = {}
    per_topic: dict[str, int] = {}
    count = 0
    last: int | None = None
    stopped_at = 0
    size = path.stat().st_size
    with path.open("rb") as stream:
        for record in _records_before_cut(stream, None):
            stopped_at = stream.tell()
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                schema = schemas.get(record.schema_id)
                msgtype = schema.name if schema is not None else ""
                connections[record.id] = Connection(record.id, record.topic, msgtype)
                if schema is not None and schema.data:
                    definitions[msgtype] = (schema.encoding, schema.data.decode("utf-8", "replace"))
            elif isinstance(record, Message) and record.channel_id in connections:
                count += 1
                topic = connections[record.channel_id].topic
                per_topic[topic] = per_topic.get(topic, 0) + 1
                last = record.log_time if last is None else max(last, record.log_time)
    if count == 0:
        raise SourceError(f"{path}: the log is cut short (no MCAP summary) and no message before the cut can be "
                          f"read ({stopped_at} of {size} bytes readable)")
    return RecoveredMcap(path, connections, definitions, count, per_topic, stopped_at, size, last)


def _typestore(definitions: dict[str, tuple[str, str]], path: Path) -> Any:
    """A typestore of the file's message definitions (as `AnyReader` makes it), ROS 2 Humble's when it has none."""
    from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY if definitions else Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    try:
        for msgtype, (encoding, text) in definitions.items():
            if encoding == "ros2msg":
                types.update(get_types_from_msg(text, msgtype))
            elif encoding in ("ros2idl", "omgidl"):
                separator = "=" * 80 + "\n"
                parts = text.split(separator)[1:] if text.startswith(f"{separator}IDL: ") else [text]
                for part in parts:
                    types.update(get_types_from_idl(part.split("\n", 1)[1] if part.startswith("IDL: ") else part))
        store.register(types)
    except Exception as exc:  # noqa: BLE001 - a schema rosbags cannot parse
        raise SourceError(f"{path}: cannot read the message definitions of the cut-short log ({exc})") from None
    return store


def _format_ns(ns: int) -> str:
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"
