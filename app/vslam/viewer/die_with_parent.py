"""Run a command that Linux kills when the process that started it dies, even by SIGKILL (`PR_SET_PDEATHSIG`).

``python -I -S die_with_parent.py [--signal NAME] PARENT_PID COMMAND...`` sets the death signal (SIGKILL, or
SIG`NAME`: tests/ray_cluster.py uses TERM, on which `ray start --block` stops its daemons), dies at once if PARENT_PID
is no longer its parent (it died before the signal was set: none would come), then replaces itself by
COMMAND (exec: same pid, session and standard streams; the death signal survives exec). `vslam.viewer.processes`
starts every viewer process through it, so no viewer outlives a SIGKILLed vslam. A `preexec_fn` would set the
signal without this extra process, but it makes `subprocess` run the interpreter's fork hooks in vslam, and a
Ctrl-C arriving during them is lost (measured: `vslam snapshot` then ran to the end and exited 0).

Standard library only, and run with ``-I -S`` (no site, no vslam import): it starts in tens of milliseconds.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def main(argv: list[str]) -> None:
    arguments = argv[1:]
    death = signal.SIGKILL
    if arguments[:1] == ["--signal"]:  # e.g. TERM, for a command that stops its own children on SIGTERM
        death, arguments = signal.Signals[f"SIG{arguments[1]}"], arguments[2:]
    parent, command = int(arguments[0]), arguments[1:]
    with contextlib.suppress(OSError, AttributeError):  # no prctl in this C library: run the command unguarded
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(death), 0, 0, 0)
    if os.getppid() != parent:
        os.kill(os.getpid(), signal.SIGKILL)
    for ignored_by_python in (signal.SIGPIPE, signal.SIGXFSZ):  # as `subprocess` gives them to a direct child
        signal.signal(ignored_by_python, signal.SIG_DFL)
    os.execv(command[0], command)


if __name__ == "__main__":
    main(sys.argv)
