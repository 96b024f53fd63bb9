"""`--trajectory-out`: one pose per frame, written and flushed as the run goes, so a killed run's file holds
the poses done so far; the final poses (the map backend's refined ones) replace it atomically at the end."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from vslam.common import ClaimedFile, OutputError, write_failure
from vslam_core.sources.base import describe_indices
from vslam_core.trajectory.io import kitti_line, tum_line

if TYPE_CHECKING:
    from vslam_core.pipeline import RunResult
    from vslam_core.results import FrameResult
    from vslam_core.sources.base import Frame

Format = Literal["kitti", "tum"]
#: The first line of a TUM trajectory written with ``header=True`` (the logging API): the source frames of its
#: rows, in order (``START:END[:STEP]``, or every index comma-separated when they are not evenly spaced), so that
#: `vslam eval --trajectory` pairs them with those ground-truth rows whatever clock the times are on. TUM readers
#: skip ``#`` lines; a KITTI file gets none (the KITTI devkit reads numbers only).
FRAMES_HEADER = "# vslam frames: "


def frames_header(indices: list[int]) -> str:
    """The `FRAMES_HEADER` line (with its newline) for rows of these source frames."""
    text = describe_indices(indices)
    spec = text if ".." not in text else ",".join(str(i) for i in indices)
    return f"{FRAMES_HEADER}{spec}\n"


class TrajectoryWriter:
    """A `FrameSink` appending each frame's pose to a claimed file. A write error (full disk) raises
    `OutputError`, which stops the run; the lines written before it stay."""

    def __init__(self, claimed: ClaimedFile, fmt: Format, header: bool = False) -> None:
        self.path = claimed.path
        self.format = fmt
        self.header = header and fmt == "tum"  # `FRAMES_HEADER`, written when the frames are known (`finish`)
        self.lines = 0
        os.ftruncate(claimed.fd, 0)  # --force over an older file
        self._fd = os.dup(claimed.fd)
        self._size = 0  # bytes of whole lines on disk
        self._written: list[np.ndarray] = []

    def __call__(self, frame: Frame, result: FrameResult) -> None:
        stamp = frame.timestamp if frame.timestamp is not None else float(frame.index)
        self._write(self._line(stamp, result.T_world_cam))
        self._written.append(result.T_world_cam)

    def _line(self, stamp: float, pose: np.ndarray) -> str:
        return kitti_line(pose) if self.format == "kitti" else tum_line(stamp, pose)

    def _write(self, text: str) -> None:
        """Append one line with unbuffered writes (in the kernel at once: a killed process keeps it; not an
        fsync, which per frame would cost more than the frame). A failed write is cut back to the last whole
        line, so the file stays readable."""
        data = text.encode("ascii")
        try:
            done = 0
            while done < len(data):
                done += os.write(self._fd, data[done:])
        except OSError as exc:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, self._size)
            raise OutputError(write_failure(self.path, exc)) from None
        self._size += len(data)
        self.lines += 1

    def finish(self, run: RunResult) -> None:
        """Close; when the run's final poses differ from those written (map backend: refined by bundle
        adjustment), write them to a temporary file beside and move it into place. On a write error the
        file written during the run stays, and `OutputError` says why."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
        final = run.poses
        header = frames_header(list(run.indices)) if self.header and run.indices else ""
        if not header and len(final) == len(self._written) and all(
                np.array_equal(a, b) for a, b in zip(final, self._written, strict=True)):
            return
        stamps = [t if t is not None else float(i) for t, i in zip(run.timestamps, run.indices, strict=True)]
        text = header + "".join(self._line(s, p) for s, p in zip(stamps, final, strict=True))
        self._replace(text)
        self.lines = len(final)

    def _replace(self, text: str) -> None:
        temporary: Path | None = None
        try:
            fd, name = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent)
            temporary = Path(name)
            with os.fdopen(fd, "w", encoding="ascii") as file:
                file.write(text)
            temporary.chmod(0o644)
            os.replace(temporary, self.path)
        except OSError as exc:
            if temporary is not None:
                temporary.unlink(missing_ok=True)
            raise OutputError(write_failure(self.path, exc) + "; it keeps the poses written during the run") from None
