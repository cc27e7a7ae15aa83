"""Faults at run time that the CLI reports in one line (exit status 1), without a traceback."""

from __future__ import annotations


class FileFault(RuntimeError):
    """A file a run needs cannot be read or written; the message is one line that names the file."""


class JobFailed(RuntimeError):
    """A job the run fanned out (``srmpc.fanout``: an evaluation shard, a training) failed; the message is one
    line naming the job and its log."""


def describe_file_fault(error: BaseException) -> str:
    """One line naming the path of a :class:`FileFault` or an ``OSError``."""
    if isinstance(error, OSError) and error.filename is not None:
        reason = error.strerror or type(error).__name__
        target = f" -> {error.filename2}" if error.filename2 is not None else ""
        return f"{error.filename}{target}: {reason}"
    return (str(error).splitlines() or [type(error).__name__])[0]
