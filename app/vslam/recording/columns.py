"""Per-frame rows of every entity, buffered and sent as columns: one `send_columns` per entity instead of one
`log` per entity per frame, which cost ~80–200 µs of Python each (~25 a frame)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import rerun as rr

from vslam_core.sources.base import Frame

FLUSH_FRAMES = 100  # buffered columns are sent at least this often (and on close)…
#: … and this often, whatever the frame rate: a killed run loses at most ~this much (+ a frame). Every chunk costs
#: ~1.2 KB in the file whatever it holds, so at 10 Hz 1.5 s instead of 1 s saves 1.2 KB a frame with `vo`, 1.4–3
#: with `map` (~35 / ~60 entities a flush); 2 s would save ~0.5 / ~1–2 KB more but lose more than 2 s to a SIGKILL.
FLUSH_SECONDS = 1.5
FLUSH_BYTES = 2**20  # ... or as soon as one entity holds this much (images, flow): memory stays flat
PENDING_JPEG_BYTES = 48 * 1024  # what a JPEG still being encoded counts as (a KITTI frame at q40: ~37 KB)


Part = tuple[Callable[..., Any], dict[str, Any]]  # an archetype's `columns` method and one row's values


@dataclass
class _Rows:
    """Buffered rows of one entity: frame indices, timestamps, and per archetype part the values and, for a
    batch entity, the number of instances in each row."""

    columns: list[Callable[..., Any]]
    batch: bool
    frames: list[int] = field(default_factory=list)
    times: list[float | None] = field(default_factory=list)
    values: list[dict[str, list[Any]]] = field(default_factory=list)
    lengths: list[list[int]] = field(default_factory=list)
    nbytes: int = 0


class ColumnBuffer:
    """Per-frame rows, sent with one `send_columns` per entity on `flush` (or sooner, once an entity holds
    `FLUSH_BYTES`). A row holds either one value per component (poses, scalars, text) or, with
    `batch=True`, an array of instances per component (points, arrows), which are concatenated and
    partitioned back into rows when sent.

    `last`: the entity `flush` sends after every other, so that in a file cut anywhere (killed run, full disk)
    a frame that has its row of `last` (the camera pose) has its rows of every entity."""

    def __init__(self, rec: rr.RecordingStream, last: str | None = None, background: bool = False) -> None:
        """`background`: the rows are turned into Arrow columns and sent by a thread of their own (in order),
        off the caller's (tracking) thread; `wait` for them, and `close`."""
        self._rec = rec
        self._last = last
        self._rows: dict[str, _Rows] = {}
        self._sender = ThreadPoolExecutor(1, thread_name_prefix="vslam-send") if background else None
        self._sending: list[Future[None]] = []

    def add(self, entity: str, frame: Frame, *parts: Part, batch: bool = False) -> None:
        rows = self._rows.get(entity)
        if rows is None:
            rows = self._rows[entity] = _Rows([columns for columns, _ in parts], batch,
                                              values=[{name: [] for name in v} for _, v in parts],
                                              lengths=[[] for _ in parts])
        rows.frames.append(frame.index)
        rows.times.append(frame.timestamp)
        for buffered, lengths, (_, values) in zip(rows.values, rows.lengths, parts, strict=True):
            for name, value in values.items():
                buffered[name].append(value)
                rows.nbytes += _size(value)
            if batch:
                lengths.append(len(next(iter(values.values()))))
        if rows.nbytes >= FLUSH_BYTES:
            self._submit(self._send, entity, self._rows.pop(entity))

    def add_rows(self, entity: str, frames: Sequence[Frame], *parts: Part, lengths: Sequence[Sequence[int]]) -> None:
        """The rows of several frames at once (a batch entity: `add(..., batch=True)` a frame at a time): each
        part's values the rows' instances concatenated, `lengths[p][i]` of part p's in the row of `frames[i]`."""
        if not frames:
            return
        rows = self._rows.get(entity)
        if rows is None:
            rows = self._rows[entity] = _Rows([columns for columns, _ in parts], True,
                                              values=[{name: [] for name in v} for _, v in parts],
                                              lengths=[[] for _ in parts])
        rows.frames.extend(frame.index for frame in frames)
        rows.times.extend(frame.timestamp for frame in frames)
        for buffered, counts, (_, values), part_lengths in zip(rows.values, rows.lengths, parts, lengths, strict=True):
            for name, value in values.items():
                buffered[name].append(value)  # concatenated with the others when sent
                rows.nbytes += _size(value)
            counts.extend(part_lengths)

    def add_scalars(self, entity: str, frames: Sequence[Frame], values: Sequence[float]) -> None:
        """`add_scalar` of several frames at once (`values[i]` at `frames[i]`)."""
        self.add_values(entity, frames, rr.Scalars.columns, scalars=values)

    def add_values(self, entity: str, frames: Sequence[Frame], make: Callable[..., Any],
                   **values: Sequence[Any]) -> None:
        """The rows of several frames at once, one value per component in each (`values[name][i]` at `frames[i]`;
        `add` a frame at a time)."""
        if not frames:
            return
        rows = self._rows.get(entity)
        if rows is None:
            rows = self._rows[entity] = _Rows([make], False, values=[{name: [] for name in values}], lengths=[[]])
        rows.frames.extend(frame.index for frame in frames)
        rows.times.extend(frame.timestamp for frame in frames)
        for name, column in values.items():
            rows.values[0][name].extend(column)

    def add_instance(self, entity: str, frame: Frame, make: Callable[..., Any], **values: Any) -> None:
        """One more instance (one value per component) of `entity` at `frame`: appended to the frame's row while
        it is buffered, else a row of its own. The viewer's text-log level filter (Rerun 0.41) shows the wrong
        level or drops a row when two rows of an entity share a time: events get one row a frame."""
        rows = self._rows.get(entity)
        if rows is None or frame.index not in rows.frames:
            self.add(entity, frame, (make, {name: [value] for name, value in values.items()}), batch=True)
            return
        row = rows.frames.index(frame.index)
        for name, value in values.items():
            rows.values[0][name][row].append(value)
            rows.nbytes += _size(value)
        rows.lengths[0][row] += 1

    def add_scalar(self, entity: str, frame: Frame, value: float) -> None:
        """`add` of one `Scalars` value, without the generic bookkeeping (~20 series per frame)."""
        rows = self._rows.get(entity)
        if rows is None:
            rows = self._rows[entity] = _Rows([rr.Scalars.columns], False, values=[{"scalars": []}], lengths=[[]])
        rows.frames.append(frame.index)
        rows.times.append(frame.timestamp)
        rows.values[0]["scalars"].append(value)

    def flush(self, then: Callable[[], None] | None = None) -> None:
        """Send every buffered row, then call `then` (on the sending thread, when in the background).

        At most one flush is in flight: a sending thread that falls behind (a starved core) holds the caller
        back, so a write that failed (a full disk) is raised here at the latest, one flush after it."""
        self.wait()
        rows, self._rows = self._rows, {}
        self._submit(self._send_all, rows, then)

    def wait(self) -> None:
        """Wait until everything flushed is sent; raise the first error of a send (or of its `then`)."""
        sending, self._sending = self._sending, []
        for job in sending:
            job.result()

    def close(self) -> None:
        """Stop the sending thread (after what it has been given)."""
        if self._sender is not None:
            self._sender.shutdown(wait=True)

    def _submit(self, send: Callable[..., None], *args: Any) -> None:
        """`send(*args)` now, or on the sending thread; an error of an earlier send is raised here."""
        if self._sender is None:
            send(*args)
            return
        self.raise_failed()
        self._sending.append(self._sender.submit(send, *args))

    def raise_failed(self) -> None:
        """Raise the error of a send that has ended (a full disk), without waiting for those still running."""
        done = [job for job in self._sending if job.done()]
        if done:
            self._sending = [job for job in self._sending if not job.done()]
            for job in done:
                job.result()

    def _send_all(self, rows: dict[str, _Rows], then: Callable[[], None] | None) -> None:
        # most entities have a row on every frame: their index columns are built once per flush
        indexes: dict[tuple[tuple[int, ...], tuple[float | None, ...]], list[rr.TimeColumn]] = {}
        last = rows.pop(self._last) if self._last is not None and self._last in rows else None
        for entity, entity_rows in rows.items():
            self._send(entity, entity_rows, indexes)
        if last is not None:
            self._send(str(self._last), last, indexes)
        if then is not None:
            then()

    def _send(self, entity: str, rows: _Rows,
              built: dict[tuple[tuple[int, ...], tuple[float | None, ...]], list[rr.TimeColumn]] | None = None) -> None:
        for values in rows.values:  # wait for values computed in the background (JPEG frames)
            for name, column in values.items():
                values[name] = [v.result() if isinstance(v, Future) else v for v in column]
        key = (tuple(rows.frames), tuple(rows.times))
        indexes = built.get(key) if built is not None else None
        if indexes is None:
            indexes = index_columns(rows.frames, rows.times)
            if built is not None:
                built[key] = indexes
        columns = []
        for make, values, lengths in zip(rows.columns, rows.values, rows.lengths, strict=True):
            if rows.batch:
                columns += make(**{name: _concatenate(v) for name, v in values.items()}).partition(lengths)
            elif make == rr.AnyValues.columns:  # its own typing of arrays: rows kept as they were given
                columns += make(**values)
            else:
                columns += make(**{name: _stacked(v) for name, v in values.items()})
        self._rec.send_columns(entity, indexes=indexes, columns=columns)


def kept_per_row(lengths: Sequence[int], kept: npt.ArrayLike) -> list[int]:
    """How many of each row's instances the (sum(lengths),) mask `kept` keeps (rows of `lengths` instances, one
    after the other): the `lengths` of `ColumnBuffer.add_rows` for the kept instances."""
    rows = np.repeat(np.arange(len(lengths)), lengths)
    return np.bincount(rows[np.asarray(kept, bool)], minlength=len(lengths)).tolist()


def _size(value: Any) -> int:
    """Rough bytes held by one buffered value."""
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, Future):
        return PENDING_JPEG_BYTES
    return len(value) if isinstance(value, bytes | str | list) else 8


def _stacked(rows: list[Any]) -> Any:
    """Rows that are arrays of one shape and type as one array, (n, *shape): the same Arrow column, built
    ~100x faster for line strips (a list of (2, 3) segments costs ~2 ms a flush, converted strip by strip)."""
    first = rows[0]
    if not isinstance(first, np.ndarray) or first.ndim == 0:
        return rows
    if all(isinstance(r, np.ndarray) and r.shape == first.shape and r.dtype == first.dtype for r in rows):
        return np.stack(rows)
    return rows


def _concatenate(batches: list[Any]) -> Any:
    """One array (or list, for text) of the instances of all rows. Flat numeric arrays become Arrow
    arrays: `AnyValues.columns` turns a numpy array into a list of one-element lists, ~70x slower."""
    if isinstance(batches[0], np.ndarray):
        values = np.concatenate(batches)
        return pa.array(values) if values.ndim == 1 else values
    return [value for batch in batches for value in batch]


EVENTS = "/events"
#: What is known only when the run ends (the drift ranking, loop searches finished at the last frame), at the
#: frames it is about: beside `/events`, whose rows of those frames are written already (one row a frame).
EVENTS_AT_END = "/events/at_end"


def add_event(columns: ColumnBuffer, frame: Frame, text: str, level: str, entity: str = EVENTS) -> None:
    """One line of the `/events` text log (or of `entity`), prefixed with the frame index."""
    columns.add_instance(entity, frame, rr.TextLog.columns, text=f"frame {frame.index}: {text}", level=level)


#: The image of a `Frame` made only to place something on the timelines.
NO_IMAGE = np.zeros((0, 0), np.uint8)

#: Stamps after this many seconds are Unix times (a ROS log's header stamps), not time since the start.
UNIX_STAMPS_AFTER_S = 1e9


def index_columns(frames: list[int], times: list[float | None]) -> list[rr.TimeColumn]:
    """The `frame` timeline of these rows, and the `time` timeline when every row has a timestamp."""
    indexes = [rr.TimeColumn("frame", sequence=np.asarray(frames, np.int64))]
    stamps = [t for t in times if t is not None]
    if len(stamps) == len(frames):
        indexes.append(time_column(stamps))
    return indexes


def time_column(times: list[float]) -> rr.TimeColumn:
    """The `time` timeline: a date and time for a log's Unix stamps, else a duration since the start. Handed to
    Rerun as an array: a list of 100 floats takes it ~25x longer (0.23 ms)."""
    seconds = np.asarray(times, np.float64)
    if times and times[0] > UNIX_STAMPS_AFTER_S:
        return rr.TimeColumn("time", timestamp=seconds)
    return rr.TimeColumn("time", duration=seconds)

