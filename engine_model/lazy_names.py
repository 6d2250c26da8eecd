"""Names a package exports but imports only when first asked for (PEP 562), for the packages
that do it (``engine_model``, ``calibration.discrepancy``; ``prognostics`` writes the same
hook out, since its ``__init__`` must not import engine_model):
a light ``import`` of the package, the heavy modules (CasADi, torch, scipy.stats) on first
use of a name that needs them.

In a package's ``__init__``::

    _LAZY = {"EngineModel": "solver.model"}          # name -> submodule that defines it
    __getattr__, __dir__ = lazy_names(__name__, _LAZY)
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping
from importlib import import_module


def lazy_names(package: str, names: Mapping[str, str]) -> tuple[Callable, Callable]:
    """The module ``__getattr__`` and ``__dir__`` of ``package`` for ``names`` (name ->
    submodule, relative to the package): a name is imported from its submodule on first
    look-up and then kept in the package's namespace, so later look-ups skip the hook."""

    def __getattr__(name: str):
        if name in names:
            value = getattr(import_module(f".{names[name]}", package), name)
            setattr(sys.modules[package], name, value)
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__():
        return sorted(set(vars(sys.modules[package])) | set(names))

    return __getattr__, __dir__
