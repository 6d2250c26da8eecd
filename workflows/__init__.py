"""The application layer: workflows that wire the simulator, the calibration and the
prognostics library into a job a user runs.

- :mod:`workflows.pipeline`  ``hyprog pipeline``: data -> calibration -> discrepancy loop ->
  features -> networks -> evaluation -> a report, resumable stage by stage
- :mod:`workflows.paper`     ``hyprog experiment paper``: the paper's experiments and
  ablations, every training run cached, and their report

Import order of hyprog's packages (a test enforces it): ``engine_model`` <- ``calibration``
<- ``prognostics`` <- ``workflows`` <- ``cli``. The libraries below never import this package.
"""
