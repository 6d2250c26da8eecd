"""hyprog.prognostics: RUL prediction from feature tables (step 2-3 of the paper's Algorithm 1).

One job per module:

- :mod:`.features`     input sets by name (``data-driven``, ``hybrid``, ablations) -> columns
- :mod:`.scaling`      min-max scaling to [-1, 1] fitted on training units
- :mod:`.splits`       development / validation / conformal-calibration rows
- :mod:`.windows`      sliding windows as strided views (no per-window copy)
- :mod:`.models`       the paper's FNN and 1-D CNN
- :mod:`.training`     the training loop (AMSGrad, early stopping, seeds)
- :mod:`.ensemble`     a trained model (one or more seeds) and its predictions
- :mod:`.conformal`    split-conformal prediction intervals
- :mod:`.checkpoint`   safe save / load (safetensors + JSON, SHA-256 checked)
- :mod:`.metrics`      RMSE, NASA score, per-cycle mean, prediction horizon, coverage
- :mod:`.baseline`     physics-only RUL from the health-index trend of theta_hat
- :mod:`.experiment`   the paper's experiments and ablations, cached per run
- :mod:`.plots`        figures (matplotlib, Agg)

This is the only package of hyprog that imports torch; importing ``prognostics`` itself does
not (the modules that need it import it).
"""
