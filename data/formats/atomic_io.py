"""Atomic file output (docs/formats.md): a temporary file beside the target, then renamed into place."""

from __future__ import annotations

import os
import re
import signal
import socket
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Iterator

TEMPORARY = re.compile(r"^\.(?P<target>.+)\.(?P<host>[A-Za-z0-9-]+)\.(?P<pid>\d+)\.[^.]+\.tmp$")


def _umask() -> int:
    """The process umask (os.umask can only be read by setting it)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _host() -> str:
    """This machine's short host name, reduced to the characters a temporary's name may hold."""
    return re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname().split(".")[0]) or "host"


def _running(pid: int) -> bool:
    """Whether a process with this id exists on this host."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def is_temporary(path: Path) -> bool:
    """Whether path is named like a temporary of :func:`atomic_open`."""
    return TEMPORARY.match(path.name) is not None


def is_stale(path: Path) -> bool:
    """Whether path is a temporary whose writer, on this host, is no longer running (killed before its rename)."""
    match = TEMPORARY.match(path.name)
    if match is None or match["host"] != _host():
        return False  # another host's writer may still be running
    pid = int(match["pid"])
    return pid != os.getpid() and not _running(pid)


def remove_stale_temporaries(folder: Path, target: str | None = None) -> None:
    """Delete the stale temporaries of the file named target (None: of any file) in folder."""
    for path in folder.glob("*.tmp"):
        match = TEMPORARY.match(path.name)
        if match and target in (None, match["target"]) and is_stale(path):
            path.unlink(missing_ok=True)


@contextmanager
def atomic_open(path: str | Path, binary: bool = False, fsync: bool = False) -> Iterator[IO]:
    """A temporary beside path open for writing (open()'s permissions): replaces path on success, vanishes on error."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(path.parent, target=path.name)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{_host()}.{os.getpid()}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb" if binary else "w") as f:
            yield f
            if fsync:
                f.flush()
                os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write text to path atomically."""
    with atomic_open(path) as f:
        f.write(text)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write bytes to path atomically."""
    with atomic_open(path, binary=True) as f:
        f.write(data)


def _exit_on_signal(signum: int, frame: object) -> None:
    """Signal handler: leave through SystemExit, so that with-blocks and finally-clauses run."""
    sys.exit(128 + signum)


def exit_on_sigterm() -> None:
    """Turn SIGTERM (kill, a scheduler, torchrun) into SystemExit(143), so temporaries are removed as for Ctrl-C."""
    signal.signal(signal.SIGTERM, _exit_on_signal)
