"""An output directory belongs to one process at a time: an exclusive advisory lock for a run's lifetime.

Two runs appending to one ``episodes.csv`` (or one ``metrics.csv``) interleave their rows, and the next
resume reads the duplicates as finished episodes. So every run of ``python -m srmpc`` takes
``fcntl.flock(LOCK_EX | LOCK_NB)`` on :data:`LOCK_NAME` inside its output directory before it writes
anything there, and holds it until it ends. A second process finds the lock taken and stops at once
(:class:`OutputDirectoryBusy`, one line naming the directory and the holder's pid and host, which the
holder writes into the lock file).

The operating system releases the lock when its holder dies, SIGKILL included, so a killed run never
leaves a stale lock: the file may stay behind, but the next run takes it over. On release the holder
deletes the lock file (and the directory, if the run created it and left it empty). Deleting a lock file
is safe because a taker checks, after locking, that the file it locked is still the one at the path,
and starts over if not. ``flock`` works across machines on a shared file system that supports it (NFSv4,
Lustre with ``flock`` mounted), which is what a SLURM job array resubmitted beside itself needs.

The lock file is in ``.gitignore`` and ``.dvcignore``: a training's output directory is a DVC output as
a whole, and a run in progress (or one killed outright) must not change it.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import socket
import time
from collections.abc import Iterator
from pathlib import Path

LOCK_NAME = ".srmpc.lock"
"""The lock file's name inside an output directory (ignored by git and DVC)."""
HOLDER_WAIT_S = 1.0
"""How long a refused process waits for the holder to write its pid into the lock file."""


class OutputDirectoryBusy(RuntimeError):
    """Another process holds the output directory's lock; the message is one line naming both."""

    def __init__(self, key: str, directory: Path, holder: str) -> None:
        self.directory, self.holder = directory, holder
        super().__init__(f"{key}={directory}: in use by {holder}, which holds {directory / LOCK_NAME}; "
                         "wait for it to end or choose another directory")


class OutputDirectoryUnwritable(RuntimeError):
    """The output directory (or its lock file) cannot be created; the message names the key and path."""


def _holder(fd: int) -> str:
    """``process <pid> on <host>`` as the holder wrote it into the lock file, waiting briefly for it."""
    deadline = time.monotonic() + HOLDER_WAIT_S
    while True:
        text = os.pread(fd, 200, 0).decode(errors="replace").split()
        if len(text) >= 2 and text[0].isdigit():
            return f"process {text[0]} on {text[1]}"
        if time.monotonic() >= deadline:
            return "another process (its pid not yet written)"
        time.sleep(0.02)


def _same_file(fd: int, path: Path) -> bool:
    try:
        on_disk = os.stat(path)
    except FileNotFoundError:
        return False
    held = os.fstat(fd)
    return (held.st_dev, held.st_ino) == (on_disk.st_dev, on_disk.st_ino)


def _acquire(directory: Path, key: str) -> int:
    """The locked file descriptor of ``directory``'s lock file, with this process written into it."""
    path = directory / LOCK_NAME
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except FileNotFoundError:  # a holder that had created the directory removed it on release
            directory.mkdir(parents=True, exist_ok=True)
            continue
        except OSError as error:
            raise OutputDirectoryUnwritable(f"{key}={directory}: cannot create its lock file {path} "
                                            f"({error.strerror or error})") from error
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as error:
            if error.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                os.close(fd)
                raise OutputDirectoryUnwritable(f"{key}={directory}: cannot lock {path} "
                                                f"({error.strerror or error})") from error
            holder = _holder(fd)
            os.close(fd)
            raise OutputDirectoryBusy(key, directory, holder) from None
        if _same_file(fd, path):  # not a file its previous holder deleted after we opened it
            break
        os.close(fd)
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()} {socket.gethostname()}\n".encode(), 0)
    return fd


@contextlib.contextmanager
def exclusive_output_dir(directory: Path, key: str) -> Iterator[Path]:
    """Hold ``directory``'s lock for the block (creating the directory if missing); ``key`` is the config
    key that named it, for the messages. Raises :class:`OutputDirectoryBusy` when another process holds
    it and :class:`OutputDirectoryUnwritable` when it cannot be created."""
    directory = Path(directory)
    created = not directory.exists()
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputDirectoryUnwritable(f"{key}={directory}: cannot write there ({error.strerror or error})"
                                        ) from error
    try:
        fd = _acquire(directory, key)
    except BaseException:
        if created:
            with contextlib.suppress(OSError):
                directory.rmdir()
        raise
    try:
        yield directory
    finally:
        with contextlib.suppress(OSError):
            os.unlink(directory / LOCK_NAME)  # still held: a taker that opened it sees it replaced
        os.close(fd)  # releases the lock
        if created:
            with contextlib.suppress(OSError):  # only if the run left it empty
                directory.rmdir()
