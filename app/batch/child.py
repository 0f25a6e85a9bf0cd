"""The child process of a batch task: `python -m app.batch.child run|refine|export ...`.

The same as `splatam ...`, except that on Linux it asks the kernel to end it (SIGTERM) when the
Dask worker that started it dies: a worker killed mid-run must not leave its run going on and
writing into the run folder that the task's retry on another worker resumes.
"""

from __future__ import annotations

import os
import sys

PARENT_ENV = "SPLATAM_BATCH_PARENT"


def die_with_parent() -> None:
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    import signal

    PR_SET_PDEATHSIG = 1
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    parent = os.environ.get(PARENT_ENV)
    if parent and os.getppid() != int(parent):     # the worker died before prctl took effect
        sys.exit(143)


def main() -> int:
    import signal
    signal.signal(signal.SIGINT, signal.default_int_handler)   # the worker ignores Ctrl-C; a run stops on it
    die_with_parent()
    from app.cli import splatam_main
    return splatam_main(sys.argv[1:])


if __name__ == "__main__":
    sys.exit(main())
