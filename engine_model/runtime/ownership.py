"""The one ownership rule of every writer: what an output path may be, and what may be replaced.

Every command that writes (datasets, feature tables, model folders, reports, predictions, the
pipeline's and the experiment's folders) checks its output with :func:`check_output` before
any work, and :mod:`.atomic` checks it again just before the new output is moved in. A writer
describes what it makes with an :class:`OutputKind`: a directory or a file, its name in words,
a recogniser ``ours(path)`` that tells an earlier output of that kind which hyprog wrote
(e.g. :func:`engine_model.datasets.provenance.written_by_hyprog`), and for a directory that
is replaced as a whole its ``layout(path)``: the files hyprog wrote in it.

The rule
--------
1. **Never the current directory** or one of its parents (replacing it would pull the ground
   from under the shell that runs hyprog).
2. **Never what the command reads.** The writer gets the command's input paths; an output that
   is an input, lies inside one (``--out MODEL/model.json``) or contains one is refused, with
   or without ``--overwrite``. Paths are compared resolved (symbolic links followed) and with
   :func:`os.path.samefile` (hard links, two spellings of one file).
3. **Never inside hyprog's own packages** (:data:`PACKAGES`: the code and the packaged sample
   data, ``data_samples/tiny`` the pipeline's default input), with or without
   ``--overwrite``: a fleet hyprog wrote there once would otherwise be replaceable like any
   other of its outputs.
4. **Never anything but a regular file or a directory.** A named pipe, a device, a socket, or
   a symbolic link to one of them is refused, even with ``--overwrite``: ``os.replace`` would
   put a regular file where the device was.
5. Nothing there, or an empty directory (empty but for hyprog's own hidden entries:
   :func:`.names.is_hyprog_entry`): written.
6. **An output hyprog wrote, of the same kind** (``ours``): replaced as a whole, atomically,
   unless it holds entries hyprog did not write. What hyprog wrote in a folder is what the
   writer's ``layout`` lists (the format's own files: a parquet dataset's
   ``unit=<n>/part-0.parquet``, a model's ``model.json`` and the weights files its manifest
   names, a report's three files) plus hyprog's hidden temporaries, backups and locks;
   anything else (``NOTES.md``, ``analysis.txt``) is the user's, and replacing the folder would
   delete it, so the replacement is refused unless ``--overwrite``.
7. **Anything else** (a regular file hyprog cannot recognise as its own, a folder of other
   files, an output of another kind): refused with an :class:`InputError` that says what is
   there, unless ``--overwrite`` (``overwrite=True``), which replaces it.

A kind that is written *into* rather than replaced (``resumed``: the pipeline's and the
experiment's folders, a feature table that ``calibrate`` resumes) deletes nothing the user put
there, so rule 6's check of other entries does not apply; those commands take no
``--overwrite`` and never write into a folder of other files.

Nothing is deleted before the new output is complete, and a failed write leaves the previous
output in place (:mod:`.atomic`).
"""

from __future__ import annotations

import os
import stat
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from engine_model.validation import InputError

from .names import is_hyprog_entry

#: hyprog's top-level packages (rule 3 of the module docstring).
PACKAGES = ("engine_model", "calibration", "prognostics", "workflows", "cli", "data_samples")


def package_holding(path: Path) -> Path | None:
    """The directory of the package of :data:`PACKAGES` that is ``path`` or holds it, None
    when there is none (found without importing the packages)."""
    import importlib.util

    target = Path(os.path.realpath(path))
    for name in PACKAGES:
        spec = importlib.util.find_spec(name)
        for loc in (spec.submodule_search_locations or []) if spec else []:
            home = Path(os.path.realpath(loc))
            if target == home or home in target.parents:
                return home
    return None


@dataclass(frozen=True)
class OutputKind:
    """What a writer makes (module docstring). ``name``: in words, for messages ("a hyprog
    model directory"); ``directory``: a directory rather than a file; ``ours(path)``: an
    existing path is an output of this kind that hyprog wrote (None: nothing is); ``layout``
    (a replaced directory): the relative POSIX paths of the files hyprog wrote in an existing
    one; ``resumed``: the writer writes into the folder and never replaces it."""

    name: str
    directory: bool
    ours: Callable[[Path], bool] | None = None
    layout: Callable[[Path], Iterable[str]] | None = None
    resumed: bool = False


def _regular_file(path: Path) -> bool:
    return path.is_file()


#: A file inside an output folder that the command already owns (checked with the folder's
#: kind: a stage's marker, a run's ``result.json``, a figure): any regular file there is one
#: hyprog wrote; a special file is still refused.
OWNED_FILE = OutputKind("a file of a hyprog output", directory=False, ours=_regular_file)


def holds_nothing(path: Path) -> bool:
    """A directory that is empty but for hyprog's hidden temporaries, backups and locks."""
    return path.is_dir() and all(is_hyprog_entry(p.name) for p in path.iterdir())


def special_kind(path: Path) -> str | None:
    """What ``path`` is in words when it is neither a regular file nor a directory (after
    following symbolic links), else None (also for nothing or a broken link there)."""
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return None
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return None
    what = ("a named pipe (FIFO)" if stat.S_ISFIFO(mode) else
            "a character device" if stat.S_ISCHR(mode) else
            "a block device" if stat.S_ISBLK(mode) else
            "a socket" if stat.S_ISSOCK(mode) else "a special file")
    return f"a symbolic link to {what}" if path.is_symlink() else what


def describe(path: Path) -> str:
    """What is at ``path``, in words (for a refusal)."""
    if path.is_symlink() and not path.exists():
        return "a broken symbolic link"
    special = special_kind(path)
    if special is not None:
        return special
    if path.is_dir():
        n = sum(1 for _ in path.iterdir())
        return f"a directory of {n} entr{'y' if n == 1 else 'ies'} that hyprog did not write"
    return "a file that hyprog did not write"


def foreign_entries(folder: Path, layout: Iterable[str]) -> list[str]:
    """The entries under ``folder`` that hyprog did not write: neither a file of ``layout``
    (relative POSIX paths), nor a folder on the way to one, nor a hyprog temporary, backup or
    lock (rule 6). A foreign folder is listed once, not its contents."""
    owned = {PurePosixPath(x) for x in layout}
    on_the_way = {d for x in owned for d in x.parents}
    found = []
    for root, dirs, files in os.walk(folder):
        rel = PurePosixPath(Path(root).relative_to(folder).as_posix())
        keep = []
        for name in dirs:
            if is_hyprog_entry(name):
                continue
            if rel / name in on_the_way and not (Path(root) / name).is_symlink():
                keep.append(name)
            else:
                found.append(str(rel / name))
        dirs[:] = keep
        found += [str(rel / n) for n in files if not is_hyprog_entry(n) and rel / n not in owned]
    return sorted(found)


def _same(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def input_relation(output: Path, source: Path) -> str | None:
    """How ``output`` stands to the input ``source``: ``"is"``, ``"is inside"``,
    ``"contains"``, or None when they are apart (rule 2)."""
    o, s = output.resolve(), source.resolve()
    if o == s or _same(output, source):
        return "is"
    if s in o.parents or any(_same(p, source) for p in output.parents if p.exists()
                             and p != Path(p.anchor)):
        return "is inside"
    if o in s.parents:
        return "contains"
    return None


def check_not_an_input(path: Path, inputs: Sequence[str | os.PathLike | None],
                       shown: str | os.PathLike | None = None) -> None:
    """Rule 2: InputError when ``path`` is, lies inside or contains one of ``inputs``."""
    for source in inputs:
        if source is None:
            continue
        how = input_relation(path, Path(os.path.abspath(source)))
        if how is not None:
            raise InputError(f"{shown or path}: {how} the input {source}; hyprog never writes"
                             " over what the command reads; choose another output")


def _refuse(path, p: Path, kind: OutputKind, recognised: bool) -> InputError:
    if recognised:  # hyprog's, but of the other kind (a directory where a file is wanted)
        what = f"a hyprog {'directory' if p.is_dir() else 'file'}, not {kind.name}"
    elif kind.resumed:
        what = f"not {kind.name}"
    else:
        what = f"{describe(p)}, not {kind.name}"
    if kind.resumed:
        return InputError(f"{path}: exists and is {what}; choose another output (a new or"
                          " empty folder, or one this command wrote)")
    return InputError(f"{path}: exists and is {what}; not replacing it without --overwrite"
                      " (which replaces it), or choose another output")


def check_output(path: str | os.PathLike, kind: OutputKind, overwrite: bool = False,
                 inputs: Sequence[str | os.PathLike | None] = ()) -> Path:
    """The absolute output path, after the rule of the module docstring for a writer of
    ``kind`` whose command reads ``inputs``; ``overwrite`` (``--overwrite``) lifts rules 6
    and 7 only. Raises InputError."""
    p = Path(os.path.abspath(path))
    cwd = Path.cwd().resolve()
    if p.resolve() == cwd or p.resolve() in cwd.parents:
        raise InputError(f"{path}: is the current directory or one of its parents; name a new"
                         " output inside it (e.g. --out fleet)")
    check_not_an_input(p, inputs, path)
    home = package_holding(p)
    if home is not None:
        raise InputError(f"{path}: is inside hyprog's package {home}; hyprog never writes "
                         "there, not even with --overwrite; choose another output")
    if not p.exists() and not p.is_symlink():
        above = next(q for q in p.parents if q.exists())
        if not above.is_dir():
            raise InputError(f"{above}: is a file, not a directory; choose another output")
        return p
    special = special_kind(p)
    if special is not None:
        raise InputError(f"{path}: is {special}, not a regular file or a directory; hyprog"
                         " never writes over it, not even with --overwrite; choose another"
                         " output")
    if kind.directory and not p.is_symlink() and holds_nothing(p):
        return p
    kind_ok = p.is_dir() == kind.directory and not p.is_symlink()
    recognised = kind.ours is not None and kind.ours(p)
    if kind_ok and recognised:
        if kind.layout is not None and not kind.resumed and not overwrite:
            extra = foreign_entries(p, kind.layout(p))
            if extra:
                n = len(extra)
                shown = ", ".join(extra[:3]) + (", ..." if n > 3 else "")
                raise InputError(f"{path}: is {kind.name} but holds {n} entr"
                                 f"{'y' if n == 1 else 'ies'} that hyprog did not write"
                                 f" ({shown}); not replacing it without --overwrite (which"
                                 " deletes them), or move them out or choose another output")
        return p
    if overwrite and not kind.resumed:
        return p
    raise _refuse(path, p, kind, recognised)


__all__ = ["OWNED_FILE", "OutputKind", "check_not_an_input", "check_output", "describe",
           "foreign_entries", "holds_nothing", "input_relation", "special_kind"]
