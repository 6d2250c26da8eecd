"""Compile CasADi functions to C shared libraries, cached on disk.

The cache key is the SHA-256 of the generated C source plus the compiler command, so a
changed model recompiles and an unchanged one is loaded by a second process without
compiling. The cache directory is ``$HYPROG_CACHE`` or ``~/.cache/hyprog``. Files are written
to a temporary name and renamed, so concurrent processes never load a half-written library.
"""

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import casadi as ca

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


def compile_functions(name: str, functions: list[ca.Function], opt: str = "-O2"
                      ) -> dict[str, ca.Function]:
    """Generate C for ``functions`` into one library and load each back as an external."""
    cc = compiler()
    if cc is None:
        raise RuntimeError("no C compiler found (set CC); use compiled=False")
    with tempfile.TemporaryDirectory() as tmp:
        cg = ca.CodeGenerator(f"{name}.c", {"with_header": False, "casadi_real": "double"})
        for f in functions:
            cg.add(f)
        src_path = Path(cg.generate(tmp + os.sep))
        src = src_path.read_bytes()
        key = hashlib.sha256(src + " ".join((cc, opt) + CFLAGS).encode()).hexdigest()[:16]
        lib = cache_dir() / f"{name}_{key}.so"
        if not lib.exists():
            tmp_lib = Path(tmp) / "out.so"
            cmd = [cc, opt, *CFLAGS, str(src_path), "-o", str(tmp_lib), "-lm"]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                raise RuntimeError(f"compiling {name} failed: {proc.stderr[-2000:]}")
            staged = lib.with_suffix(f".{os.getpid()}.tmp")
            shutil.copyfile(tmp_lib, staged)
            os.replace(staged, lib)
    return {f.name(): ca.external(f.name(), str(lib)) for f in functions}
