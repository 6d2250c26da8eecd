"""Compile CasADi functions to C shared libraries, cached on disk.

The cache key is the SHA-256 of the generated C source plus the compiler command, so a
changed model recompiles and an unchanged one is loaded by a second process without
compiling. The cache directory is ``$HYPROG_CACHE`` or ``~/.cache/hyprog``. Files are written
atomically (:mod:`engine_model.runtime.atomic`), so concurrent processes never load a
half-written library.
"""

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import casadi as ca

from engine_model.runtime.atomic import atomic_output
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
    cc = compiler()
    if cc is None:
        raise RuntimeError("no C compiler found (set CC); use compiled=False")
    with tempfile.TemporaryDirectory() as tmp:
        cg = ca.CodeGenerator(f"{name}.c", {"with_header": False, "casadi_real": "double"})
        for f in functions:
            cg.add(f)
        src_path = Path(cg.generate(tmp + os.sep))
        src = src_path.read_bytes() + b"".join(Path(p).read_bytes() for p in extra_sources)
        flags = tuple(extra_flags) + tuple(optional_flags)
        key = hashlib.sha256(src + " ".join((cc, opt) + CFLAGS + flags).encode()
                             ).hexdigest()[:16]
        lib = cache_dir() / f"{name}_{key}.so"
        if not lib.exists():
            tmp_lib = Path(tmp) / "out.so"
            sources = [str(src_path), *map(str, extra_sources)]
            err = _build(cc, opt, sources, flags, tmp_lib)
            if err is not None and optional_flags:
                err = _build(cc, opt, sources, tuple(extra_flags), tmp_lib)
            if err is not None:
                raise RuntimeError(f"compiling {name} failed: {err}")
            with atomic_output(lib, OWNED_FILE) as staged:
                shutil.copyfile(tmp_lib, staged)
    out = {f.name(): ca.external(f.name(), str(lib)) for f in functions}
    out["__library__"] = str(lib)
    return out
