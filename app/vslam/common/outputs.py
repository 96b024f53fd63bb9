"""A run's output files: unique default names, exclusive creation, and write errors as one line.

Every output (`vslam run`'s recording and trajectory, the files `crop`, `compare` and `repair` write) is
*claimed* before anything is written to it: created with ``O_EXCL`` (an existing file is never replaced
without ``--force``) and held with an exclusive ``flock`` for as long as the command writes it, so two
commands never write one file; the kernel drops the lock when the process dies, even by SIGKILL.
"""

from __future__ import annotations

import errno
import fcntl
import os
import resource
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from vslam_core.errors import VslamError
from vslam_core.sources.base import is_utf8_path, shown_path

RECORDINGS = Path("recordings")
#: Free space below which a failed write is put down to a full disk (file systems keep a few blocks back).
FULL_DISK_BYTES = 1 << 20


class OutputError(VslamError):
    """An output file cannot be created or written (exists already, in use, disk full…)."""


@dataclass
class ClaimedFile:
    """An output file this process holds: `fd` carries the exclusive lock until `release`."""

    path: Path
    fd: int
    created: bool  # this process created it (False: `--force` over an existing file)

    def release(self, keep: bool = True) -> None:
        """Drop the lock; `keep=False` removes a file this process created if nothing was written to it."""
        if self.fd < 0:
            return
        try:
            if not keep and self.created and self._still_empty():
                self.path.unlink(missing_ok=True)
        finally:
            os.close(self.fd)
            self.fd = -1


    def _still_empty(self) -> bool:
        """The path still names the file we created (not one moved there since) and it is empty."""
        try:
            mine, now = os.fstat(self.fd), self.path.stat()
        except OSError:
            return False
        return (mine.st_dev, mine.st_ino) == (now.st_dev, now.st_ino) and mine.st_size == 0


@contextmanager
def claimed(path: Path, force: bool, what: str) -> Iterator[ClaimedFile]:
    """`claim` for the length of a block that writes `path` (usually by moving a finished file onto it);
    if the block fails, the empty file claimed for it is removed."""
    file = claim(path, force, what)
    done = False
    try:
        yield file
        done = True
    finally:
        file.release(keep=done)


def run_id() -> str:
    """A short random id that tells apart runs started in the same second."""
    return uuid.uuid4().hex[:6]


def default_recording(source_name: str, frames: str, now: datetime | None = None, rid: str | None = None) -> Path:
    """``recordings/<source>[_<frames>]_<date>-<time>-<run id>.rrd``."""
    selection = "" if frames == ":" else "_" + frames.replace(":", "-")
    stamp = (now or datetime.now()).strftime("%Y%m%d-%H%M%S")
    return RECORDINGS / f"{source_name}{selection}_{stamp}-{rid or run_id()}.rrd"


def claim(path: Path, force: bool, what: str) -> ClaimedFile:
    """Create `path` for this process alone (its folder too), or raise `OutputError` in one line: it exists
    and `force` is off, another command is writing it, or it cannot be created."""
    if path.is_dir():
        raise OutputError(f"{path}: is a folder, not a {what} file")
    if what == "recording" and not is_utf8_path(path):  # Rerun's file writer takes UTF-8 paths only
        raise OutputError(f"{shown_path(path)}: a recording path must be valid UTF-8 (Rerun cannot write to this "
                          "name); choose another")
    ensure_folder(path.parent, "output folder")
    flags = os.O_WRONLY | os.O_CREAT | os.O_CLOEXEC
    created = True
    try:
        fd = os.open(path, flags | os.O_EXCL, 0o644)
    except FileExistsError:
        if _locked_by_another(path):
            raise OutputError(f"{path}: another run is writing this {what}") from None
        if not force:
            raise OutputError(f"{path}: {what} exists already (use --force to replace it)") from None
        created = False
        fd = _open(path, flags, what)
    except OSError as exc:
        raise OutputError(f"{path}: cannot create {what} ({exc.strerror})") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:  # a racing command locked it between our open and our lock: it wins
        os.close(fd)
        raise OutputError(f"{path}: another run is writing this {what}") from None
    return ClaimedFile(path, fd, created)


def _open(path: Path, flags: int, what: str) -> int:
    try:
        return os.open(path, flags, 0o644)
    except OSError as exc:
        raise OutputError(f"{path}: cannot open {what} for writing ({exc.strerror})") from None


def _locked_by_another(path: Path) -> bool:
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError:
        return True
    finally:
        os.close(fd)  # also drops the shared lock, if we got it
    return False


def ensure_folder(folder: Path, what: str) -> None:
    """Create `folder` (and parents) or raise `OutputError` in one line."""
    folder = folder if str(folder) else Path(".")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{folder}: cannot create {what} ({exc.strerror})") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"{folder}: {what} is not writable")


def write_failure(path: Path, exc: OSError | None = None) -> str:
    """Why writing `path` failed, in words a user can act on: a full disk (and which), the file size limit,
    or the system's message. Without `exc` (Rerun's writer thread does not say why it stopped) the cause
    is read from the file system."""
    code = exc.errno if exc is not None else likely_errno(path)
    if code in (errno.ENOSPC, errno.EDQUOT):
        return f"{path}: disk full (no space left on {mount_point(path)})"
    if code == errno.EFBIG:
        return f"{path}: file size limit reached (ulimit -f)"
    if exc is not None:
        return f"{path}: cannot write ({exc.strerror or exc.__class__.__name__})"
    return f"{path}: cannot write (the Rerun file writer stopped)"


def likely_errno(path: Path) -> int | None:
    """ENOSPC when `path`'s file system is (nearly) full, EFBIG when `path` is at the file size limit, else None."""
    try:
        stats = os.statvfs(path.parent if str(path.parent) else Path("."))
        if min(stats.f_bavail, stats.f_bfree) * stats.f_frsize < FULL_DISK_BYTES:
            return errno.ENOSPC
        limit, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
        if limit != resource.RLIM_INFINITY and path.stat().st_size + FULL_DISK_BYTES > limit:
            return errno.EFBIG
    except OSError:
        return None
    return None


def mount_point(path: Path) -> str:
    """The mount point of the file system holding `path` (where a user must free space)."""
    current = path.absolute().parent
    while not os.path.ismount(current) and current != current.parent:
        current = current.parent
    return str(current)


#: Writers stuck for good (see `hold_stuck_writer`); the process ends without waiting for them.
_STUCK_WRITERS: list[object] = []


def hold_stuck_writer(writer: object) -> None:
    """Keep a writer whose thread will never answer (Rerun's, after its file sink died mid-flush) alive until
    the process ends: dropping or disconnecting it would wait for that thread forever. `vslam.cli.entry` then ends
    the process without the exit handlers that would wait for it too."""
    _STUCK_WRITERS.append(writer)


def stuck_writers() -> bool:
    return bool(_STUCK_WRITERS)


#: Held (flock) by the command writing a report folder: `vslam eval --report`.
FOLDER_LOCK = ".vslam.lock"


def lock_folder(folder: Path, what: str) -> int:
    """Hold an exclusive lock on `folder` (its `FOLDER_LOCK` file) for the rest of this process, so two
    commands never write one folder; the kernel drops it when the process ends, even by SIGKILL. Returns the
    descriptor; `OutputError` in one line if another command holds the folder."""
    ensure_folder(folder, what)
    try:
        fd = os.open(folder / FOLDER_LOCK, os.O_WRONLY | os.O_CREAT | os.O_CLOEXEC, 0o644)
    except OSError as exc:
        raise OutputError(f"{folder}: cannot lock the {what} ({exc.strerror})") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise OutputError(f"{folder}: another command is writing this {what}") from None
    return fd
