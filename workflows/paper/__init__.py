"""The paper's experiment (Arias Chao et al., *Fusing physics-based and deep learning
models for prognostics*): the main table, the prediction horizon, the ablations and the
conformal part, on a feature table, every training run cached.

- :mod:`.plan`          the parts, input sets, perturbations and the runs a configuration selects
- :mod:`.experiment`    the runs: cache key, resume, perfect calibration, perturbations
- :mod:`.paper_report`  the report: per-run CSV, aggregated tables, the paper's claims, figures
"""

from .experiment import run_experiment
from .plan import PARTS, ExperimentConfig

__all__ = ["PARTS", "ExperimentConfig", "run_experiment"]
