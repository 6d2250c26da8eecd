"""Whose is an existing output path: a writer replaces only what hyprog wrote.

A writer given an output path that already holds something (:func:`check_output`):

- nothing there, or an empty directory: written;
- an output hyprog wrote, of the same kind (the writer's recogniser ``ours`` says so, e.g.
  :func:`engine_model.datasets.provenance.written_by_hyprog` for a dataset): replaced as a
  whole, atomically;
- anything else (a folder of other files, a regular file, a dataset of the other kind: a
  directory where a file is to be written or the reverse): refused with an
  :class:`~engine_model.validation.InputError` that says what is there, unless the caller
  passes ``overwrite=True`` (``hyprog ... --overwrite``);
- the current directory or one of its parents: always refused (replacing it would pull the
  ground from under the shell that runs hyprog).

Nothing is deleted before the new output is complete (:mod:`.atomic`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from engine_model.validation import InputError


def is_empty_dir(path: Path) -> bool:
    return path.is_dir() and not any(path.iterdir())


def describe(path: Path) -> str:
    """What is at ``path``, in words (for a refusal)."""
    if path.is_symlink() and not path.exists():
        return "a broken symbolic link"
    if path.is_dir():
        n = sum(1 for _ in path.iterdir())
        return f"a directory of {n} entr{'y' if n == 1 else 'ies'} that hyprog did not write"
    if path.is_file():
        return "a file that hyprog did not write"
    return "something that is not a file or a directory"


def check_output(path: str | os.PathLike, directory: bool, overwrite: bool = False,
                 ours: Callable[[Path], bool] | None = None, want: str | None = None) -> Path:
    """The absolute output path, after the checks of the module docstring. ``directory``: the
    writer makes a directory rather than a file; ``ours(path)`` recognises an output of this
    writer's kind that hyprog wrote (none: nothing is recognised); ``want`` names what the
    writer makes, for the refusal. Raises InputError."""
    p = Path(os.path.abspath(path))
    cwd = Path.cwd().resolve()
    if p.resolve() == cwd or p.resolve() in cwd.parents:
        raise InputError(f"{path}: is the current directory or one of its parents; name a new"
                         " output inside it (e.g. --out fleet)")
    if not p.exists() and not p.is_symlink():
        return p
    if directory and is_empty_dir(p):
        return p
    kind_ok = p.is_dir() == directory and not p.is_symlink()
    hyprogs = ours is not None and ours(p)
    if kind_ok and hyprogs:
        return p
    if overwrite:
        return p
    want = want or ("a directory" if directory else "a file")
    what = f"a hyprog {'directory' if p.is_dir() else 'file'}" if hyprogs else describe(p)
    raise InputError(f"{path}: exists and is {what}; hyprog writes {want} there only with"
                     " --overwrite (which replaces it), or choose another output")


__all__ = ["check_output", "describe", "is_empty_dir"]
