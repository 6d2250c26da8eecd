"""hyprog.engine_model: 0D two-spool high-bypass turbofan performance model in CasADi."""

from .channels import OUTPUT_NAMES, THETA_NAMES, W_NAMES, XS_NAMES, XV_NAMES
from .design import DesignSpec, EngineDesign, design_engine
from .model import EngineModel, ResidualSystem, SolveResult
from .validation import ENVELOPE, InputError

__all__ = [
    "EngineModel", "ResidualSystem", "SolveResult", "DesignSpec", "EngineDesign",
    "design_engine", "InputError", "ENVELOPE", "OUTPUT_NAMES", "THETA_NAMES", "W_NAMES",
    "XS_NAMES", "XV_NAMES",
]
