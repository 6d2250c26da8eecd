"""Atomic output helpers (engine_model.runtime.atomic): what a killed writer leaves is cleaned
by the next writer of the same output, and nothing else is touched."""

from __future__ import annotations

import subprocess
import sys

from engine_model.runtime.atomic import (
    host_name,
    remove_stale_temporaries,
    remove_stale_temporaries_of,
    swap_into_place,
    writer_gone,
)


def dead_pid() -> int:
    """The id of a process of this host that has ended."""
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_a_replaced_folder_is_backed_up_under_a_name_that_carries_its_writer(tmp_path):
    target, tmp = tmp_path / "out", tmp_path / ".out.tmp-x"
    target.mkdir()
    (target / "a").write_text("old")
    tmp.mkdir()
    (tmp / "a").write_text("new")
    swap_into_place(tmp, target)
    assert (target / "a").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # the backup is gone


def test_the_stale_backup_of_a_writer_killed_between_its_renames_is_put_back(tmp_path):
    """Killed after moving the old folder aside and before moving the new one in: the old
    output lives only in the backup, so the next writer puts it back under its name."""
    pid = dead_pid()
    backup = tmp_path / f".out.old-{host_name()}-{pid}-0123abcd"
    backup.mkdir()
    (backup / "a").write_text("old")
    assert writer_gone(backup.name)
    assert remove_stale_temporaries_of(tmp_path / "out") == 1
    assert (tmp_path / "out" / "a").read_text() == "old"
    assert not backup.exists()
    # killed after the second rename: the output is there, the backup is only deleted
    backup.mkdir()
    (backup / "a").write_text("older")
    assert remove_stale_temporaries(tmp_path) == 1
    assert (tmp_path / "out" / "a").read_text() == "old" and not backup.exists()


def test_cleaning_one_output_touches_only_its_own_stale_temporaries(tmp_path):
    pid = dead_pid()
    mine = tmp_path / f".model.tmp-{host_name()}-{pid}-abc"
    live = tmp_path / f".model.tmp-{host_name()}-{1}-abc"  # pid 1 runs: a live writer's
    other = tmp_path / f".other.tmp-{host_name()}-{pid}-abc"
    deep = tmp_path / "sub" / f".model.tmp-{host_name()}-{pid}-abc"
    deep.parent.mkdir()
    for p in (mine, live, other, deep):
        p.mkdir()
    assert remove_stale_temporaries_of(tmp_path / "model") == 1
    assert not mine.exists() and live.exists() and other.exists() and deep.exists()
    # the folder-wide clean (an output folder's own contents) reaches every stale one
    assert remove_stale_temporaries(tmp_path) == 2
    assert live.exists() and not other.exists() and not deep.exists()


def test_names_that_are_not_hyprog_temporaries_are_never_touched(tmp_path):
    """Another program's or a user's hidden files, and hyprog names whose own output name holds
    '.tmp-' or '.old-', are read from the right: only a dead writer's entries of the asked
    output go."""
    pid = dead_pid()
    keep = [".bashrc.old-2019", ".profile.old-1", ".state.tmp-swap", ".cnn.old-before-retrain"]
    for name in keep:
        (tmp_path / name).write_text("user")
    live_other = tmp_path / f".run.tmp-1.tmp-{host_name()}-{1}-abc"  # output 'run.tmp-1'
    dead_other = tmp_path / f".run.tmp-1.tmp-{host_name()}-{pid}-abc"
    live_other.write_text("x")
    dead_other.write_text("x")
    assert remove_stale_temporaries_of(tmp_path / "run") == 0  # none is output 'run''s
    assert live_other.exists() and dead_other.exists()
    assert remove_stale_temporaries(tmp_path) == 1  # the dead writer's only
    assert not dead_other.exists() and live_other.exists()
    assert sorted(p.name for p in tmp_path.iterdir() if p.name in keep) == sorted(keep)
    # a backup named for output 'a.old-b' goes back under that name, not 'a'
    backup = tmp_path / f".a.old-b.old-{host_name()}-{pid}-0123abcd"
    backup.mkdir()
    assert remove_stale_temporaries(tmp_path) == 1
    assert (tmp_path / "a.old-b").is_dir() and not (tmp_path / "a").exists()


def test_a_signal_between_the_two_renames_puts_the_old_output_back(tmp_path, monkeypatch):
    import os

    import pytest

    from engine_model.runtime import atomic

    target, tmp = tmp_path / "out", tmp_path / ".out.tmp-x"
    target.mkdir()
    (target / "a").write_text("old")
    tmp.mkdir()
    real = os.replace
    calls = []

    def replace(src, dst):
        calls.append(dst)
        real(src, dst)
        if len(calls) == 1:
            raise KeyboardInterrupt  # as if Ctrl-C landed right after the first rename

    monkeypatch.setattr(atomic.os, "replace", replace)
    with pytest.raises(KeyboardInterrupt):
        swap_into_place(tmp, target)
    monkeypatch.setattr(atomic.os, "replace", real)
    assert (target / "a").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".out.tmp-x", "out"]
