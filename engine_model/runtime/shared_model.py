"""One engine model per process for every caller that wants the default one (the ``hyprog``
commands, the benchmarks), so that it is built, compiled or loaded from the C cache, and
tabulated once; and one per set of effects (:func:`process_model`: an adapted model, a
simulator's truth, a worker's single-threaded variant).

>>> from engine_model.runtime.shared_model import default_model
>>> default_model() is default_model()
True
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from engine_model.solver.model import EngineModel

_MODELS: dict[bool, EngineModel] = {}
_VARIANTS: dict[tuple, EngineModel] = {}


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


def process_model(effects: Sequence[str] = (), threads: int | None = None):
    """The engine model of this process with ``effects`` (specification strings, their
    parameters held at the given values), built once per process and kept, so that a worker
    (Dask or a process pool) builds it for its first task only and the simulate and calibrate
    tasks share it: the process-wide :func:`default_model` when there are no
    effects and ``threads`` is None, else a variant on ``threads`` threads (1 in a worker).
    The thread count changes no number (the samples are independent)."""
    effects = tuple(effects)
    if threads is None and not effects:
        return default_model()
    key = (effects, threads)
    if key not in _VARIANTS:
        from engine_model.physics.effects import parse_effect_spec
        from engine_model.solver.model import EngineModel

        _VARIANTS[key] = EngineModel(effects=[parse_effect_spec(e) for e in effects],
                                     n_threads=threads)
    return _VARIANTS[key]
