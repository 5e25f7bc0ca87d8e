"""Atomic outputs: replaced whole or not at all, with the permissions a plain open() gives."""

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from data.formats.atomic_io import _host, atomic_open, atomic_write_bytes, atomic_write_text, is_stale, is_temporary


def test_write_replaces_the_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "sub" / "out.json"
    atomic_write_text(path, "old")
    atomic_write_bytes(path, b"new")
    assert path.read_bytes() == b"new"
    assert [p.name for p in path.parent.iterdir()] == ["out.json"]


def test_an_error_while_writing_keeps_the_old_file(tmp_path):
    path = tmp_path / "out.txt"
    atomic_write_text(path, "complete")
    with pytest.raises(RuntimeError):
        with atomic_open(path) as f:
            f.write("half")
            raise RuntimeError("interrupted")
    assert path.read_text() == "complete"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_permissions_follow_the_umask_not_mkstemp(tmp_path):
    old = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "a.txt", "x")
    finally:
        os.umask(old)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o644


def test_a_temporary_is_named_after_its_target_and_removed_on_keyboard_interrupt(tmp_path):
    path = tmp_path / "poses3d.json"
    with pytest.raises(KeyboardInterrupt):
        with atomic_open(path) as f:
            (tmp,) = [p for p in tmp_path.iterdir()]
            assert tmp.name.startswith(".poses3d.json.") and tmp.suffix == ".tmp" and is_temporary(tmp)
            f.write("half")
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_sigterm_removes_the_temporary(tmp_path):
    code = (
        "import time; from data.formats.atomic_io import atomic_open, exit_on_sigterm\n"
        "exit_on_sigterm()\n"
        f"with atomic_open({str(tmp_path / 'out.txt')!r}) as f:\n"
        "    f.write('half'); f.flush(); print('writing', flush=True); time.sleep(60)\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, cwd=Path(__file__).resolve().parents[1]
    )
    assert proc.stdout.readline().strip() == "writing" and len(list(tmp_path.iterdir())) == 1
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=30) == 143
    assert list(tmp_path.iterdir()) == []


def test_stale_temporaries_of_killed_writers_are_removed_and_live_ones_kept(tmp_path):
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    ).stdout.strip()  # a pid that has exited
    host = _host()
    stale = tmp_path / f".out.txt.{host}.{dead}.abc123.tmp"
    live = tmp_path / f".out.txt.{host}.{os.getpid()}.def456.tmp"
    elsewhere = tmp_path / f".out.txt.otherhost.{dead}.ghi789.tmp"
    for p in (stale, live, elsewhere):
        p.write_text("half")
    assert is_stale(stale) and not is_stale(live) and not is_stale(elsewhere)
    atomic_write_text(tmp_path / "out.txt", "whole")  # the next write of that target cleans up
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["out.txt", live.name, elsewhere.name])
