"""Atomic output helpers (engine_model.datasets.atomic): what a killed writer leaves is cleaned
by the next writer of the same output, and nothing else is touched."""

from __future__ import annotations

import subprocess
import sys

from engine_model.datasets.atomic import (
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
