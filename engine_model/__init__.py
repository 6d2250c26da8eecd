"""hyprog.engine_model: 0D two-spool high-bypass turbofan performance model in CasADi.

The light names (channel groups, ``InputError``, ``ENVELOPE``) are imported eagerly; the
model and the design (which import CasADi) load on first use through a module
``__getattr__`` (PEP 562), so ``from engine_model import EngineModel`` works while
``import engine_model.datasets`` (reading data) never imports CasADi.
"""

from .channels import OUTPUT_NAMES, THETA_NAMES, W_NAMES, XS_NAMES, XV_NAMES
from .lazy_names import lazy_names
from .validation import ENVELOPE, InputError

# name -> submodule that defines it, imported when the name is first asked for
_LAZY = {
    "EngineModel": "solver.model",
    "ResidualSystem": "solver.model",
    "SolveResult": "solver.model",
    "DesignSpec": "physics.design",
    "EngineDesign": "physics.design",
    "design_engine": "physics.design",
}

__all__ = [
    "EngineModel", "ResidualSystem", "SolveResult", "DesignSpec", "EngineDesign",
    "design_engine", "InputError", "ENVELOPE", "OUTPUT_NAMES", "THETA_NAMES", "W_NAMES",
    "XS_NAMES", "XV_NAMES",
]

__getattr__, __dir__ = lazy_names(__name__, _LAZY)
