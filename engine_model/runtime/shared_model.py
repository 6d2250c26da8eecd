"""One engine model per process for every caller that wants the default one (the ``hyprog``
commands, the benchmarks), so that it is built, compiled or loaded from the C cache, and
tabulated once.

>>> from engine_model.runtime.shared_model import default_model
>>> default_model() is default_model()
True
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from engine_model.solver.model import EngineModel

_MODELS: dict[bool, EngineModel] = {}


def default_model(compiled: bool = True) -> EngineModel:
    """The process-wide :class:`engine_model.EngineModel` without optional effects
    (``compiled``: the C code path, else CasADi's virtual machine), built on first use."""
    if compiled not in _MODELS:
        from engine_model.solver.model import EngineModel

        _MODELS[compiled] = EngineModel(compiled=compiled)
    return _MODELS[compiled]


def is_built(compiled: bool = True) -> bool:
    """Whether :func:`default_model` already holds that model (a call will not build it)."""
    return compiled in _MODELS
