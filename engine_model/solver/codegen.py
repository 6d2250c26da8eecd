"""Compile CasADi functions to C shared libraries, cached on disk.

:func:`compile_functions`: the cache key is the SHA-256 of the generated C source plus the
compiler command, so a changed model recompiles and an unchanged one is loaded by a second
process without compiling. :func:`compile_keyed`: the caller gives a key computed without the
functions (e.g. from the definitions they are derived from), so that functions that are slow
to build (the engine's exact sensitivities: about 1 s of CasADi graph work, half of a model's
start-up) are built only when their library is not in the cache; :func:`compile_keyed_all`
does so for several libraries at once, their compilers running side by side (a model's two
libraries: 41 s -> 25 s for a first build on 2 cores, 2026-11-28). The cache directory is
``$HYPROG_CACHE`` or ``~/.cache/hyprog``. Files are written atomically
(:mod:`engine_model.runtime.atomic`), so concurrent processes never load a half-written
library, and a library is built under an exclusive lock
(:func:`engine_model.runtime.build_lock.build_lock`), so that of several processes that need
the same library at once (pytest-xdist workers, the pipeline's worker processes) one compiles
it and the others wait and load it, instead of each spending the same 20-40 s of the
compiler.
"""

import hashlib
import os
import shutil
import subprocess
import tempfile
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import casadi as ca

from engine_model.runtime.atomic import atomic_output
from engine_model.runtime.build_lock import build_lock
from engine_model.runtime.ownership import OWNED_FILE

CFLAGS = ("-fPIC", "-shared", "-fno-math-errno")


def cache_dir() -> Path:
    d = Path(os.environ.get("HYPROG_CACHE", Path.home() / ".cache" / "hyprog"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def compiler() -> str | None:
    for cc in (os.environ.get("CC"), "gcc", "cc", "clang"):
        if cc and shutil.which(cc):
            return cc
    return None


def _build(cc: str, opt: str, sources: list[str], flags: tuple, out: Path) -> str | None:
    cmd = [cc, opt, *CFLAGS, *flags, *sources, "-o", str(out), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    return None if proc.returncode == 0 else proc.stderr[-2000:]


def compile_functions(name: str, functions: list[ca.Function], opt: str = "-O2",
                      extra_sources: tuple = (), extra_flags: tuple = (),
                      optional_flags: tuple = ()) -> dict[str, ca.Function]:
    """Generate C for ``functions`` into one library and load each back as an external.

    ``extra_sources`` (paths of hand-written C files, e.g. the batched Newton driver) are
    compiled into the same library with ``extra_flags``; ``optional_flags`` (e.g.
    ``-fopenmp``) are dropped if the compiler rejects them. The library path is returned
    under the key ``"__library__"`` for callers that load it with ctypes as well.
    """
    cc = _compiler_or_fail()
    with tempfile.TemporaryDirectory() as tmp:
        src_path = _generate(name, functions, tmp)
        src = src_path.read_bytes() + b"".join(Path(p).read_bytes() for p in extra_sources)
        key = hashlib.sha256(src + _command(cc, opt, extra_flags, optional_flags)).hexdigest()[:16]
        lib = cache_dir() / f"{name}_{key}.so"
        if not lib.exists():
            with build_lock(lib):
                if not lib.exists():  # not built meanwhile by the process that held the lock
                    _compile(cc, name, src_path, lib, opt, extra_sources, extra_flags,
                             optional_flags)
    return _load(lib, [f.name() for f in functions])


@dataclass(frozen=True)
class KeyedLibrary:
    """One library for :func:`compile_keyed_all`: the functions named ``names`` that
    ``build()`` returns, identified by ``key`` (module docstring), compiled with ``opt``,
    ``extra_sources``, ``extra_flags`` and, where the compiler takes them, ``optional_flags``."""

    name: str
    key: str
    names: tuple
    build: Callable[[], list]
    opt: str = "-O2"
    extra_sources: tuple = ()
    extra_flags: tuple = ()
    optional_flags: tuple = ()


def compile_keyed(name: str, key: str, names: list[str], build: Callable[[], list],
                  opt: str = "-O2", extra_sources: tuple = (), extra_flags: tuple = (),
                  optional_flags: tuple = ()) -> dict[str, ca.Function]:
    """:func:`compile_functions` for functions named ``names`` whose definitions ``key``
    identifies (module docstring): the library is looked up by ``key``, the extra sources and
    the compiler command, and ``build()`` (returning the Functions) is called only when it is
    not in the cache. The caller's key must change whenever the generated code would."""
    job = KeyedLibrary(name, key, tuple(names), build, opt, tuple(extra_sources),
                       tuple(extra_flags), tuple(optional_flags))
    return compile_keyed_all([job])[0]


def compile_keyed_all(jobs: list[KeyedLibrary]) -> list[dict[str, ca.Function]]:
    """:func:`compile_keyed` for several libraries at once, whose compilers run side by side:
    the libraries missing from the cache are built one after the other (CasADi's graph work
    and code generation stay in this thread), and each library's compiler starts as soon as
    its source is written, so that a model's libraries compile in about the time of the
    largest on two cores. The locks (:func:`build_lock`) are taken in the order of
    ``jobs``, so processes asking for the same libraries never wait on each other in a
    circle."""
    cc = _compiler_or_fail()
    libs = [_keyed_path(cc, job) for job in jobs]
    missing = [(job, lib) for job, lib in zip(jobs, libs, strict=True) if not lib.exists()]
    if missing:
        with ExitStack() as held:
            for _, lib in missing:
                held.enter_context(build_lock(lib))
            tmp = held.enter_context(tempfile.TemporaryDirectory())
            with ThreadPoolExecutor(max_workers=len(missing)) as pool:
                running = []
                for i, (job, lib) in enumerate(missing):
                    if lib.exists():  # built meanwhile by the process that held the lock
                        continue
                    functions = job.build()
                    built = [f.name() for f in functions]
                    if built != list(job.names):
                        raise RuntimeError(f"{job.name}: built {built}, expected "
                                           f"{list(job.names)}")
                    folder = Path(tmp) / str(i)
                    folder.mkdir()
                    src_path = _generate(job.name, functions, str(folder))
                    running.append(pool.submit(
                        _compile, cc, job.name, src_path, lib, job.opt, job.extra_sources,
                        job.extra_flags, job.optional_flags))
                for done in running:
                    done.result()
    return [_load(lib, list(job.names)) for job, lib in zip(jobs, libs, strict=True)]


def _keyed_path(cc: str, job: KeyedLibrary) -> Path:
    """Where :func:`compile_keyed_all` caches ``job``'s library: its name and a hash of its
    key, its extra sources and the compiler command."""
    material = job.key.encode() + b"".join(Path(p).read_bytes() for p in job.extra_sources)
    full = hashlib.sha256(material + _command(cc, job.opt, job.extra_flags,
                                              job.optional_flags))
    return cache_dir() / f"{job.name}_k{full.hexdigest()[:16]}.so"


def _compiler_or_fail() -> str:
    cc = compiler()
    if cc is None:
        raise RuntimeError("no C compiler found (set CC); use compiled=False")
    return cc


def _command(cc: str, opt: str, extra_flags: tuple, optional_flags: tuple) -> bytes:
    """The compiler command, as part of a cache key."""
    return " ".join((cc, opt) + CFLAGS + tuple(extra_flags) + tuple(optional_flags)).encode()


def _generate(name: str, functions: list[ca.Function], tmp: str) -> Path:
    """C source of ``functions`` in the folder ``tmp``."""
    cg = ca.CodeGenerator(f"{name}.c", {"with_header": False, "casadi_real": "double"})
    for f in functions:
        cg.add(f)
    return Path(cg.generate(tmp + os.sep))


def _compile(cc: str, name: str, src_path: Path, lib: Path, opt: str, extra_sources: tuple,
             extra_flags: tuple, optional_flags: tuple) -> None:
    """Compile ``src_path`` and the extra sources into the cached library ``lib``
    (written atomically); ``optional_flags`` are dropped if the compiler rejects them."""
    tmp_lib = src_path.parent / "out.so"
    sources = [str(src_path), *map(str, extra_sources)]
    err = _build(cc, opt, sources, tuple(extra_flags) + tuple(optional_flags), tmp_lib)
    if err is not None and optional_flags:
        err = _build(cc, opt, sources, tuple(extra_flags), tmp_lib)
    if err is not None:
        raise RuntimeError(f"compiling {name} failed: {err}")
    with atomic_output(lib, OWNED_FILE) as staged:
        shutil.copyfile(tmp_lib, staged)


def _load(lib: Path, names: list[str]) -> dict[str, ca.Function]:
    """The functions ``names`` of the library ``lib``, and its path under ``"__library__"``."""
    out = {n: ca.external(n, str(lib)) for n in names}
    out["__library__"] = str(lib)
    return out
