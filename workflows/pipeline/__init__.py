"""``hyprog pipeline``: from a fleet's data to RUL and a report a person reads, in one command.

One job per module:

- :mod:`.config`           the TOML configuration: every option of every stage, checked
- :mod:`.state`            fingerprints of a stage's configuration and input; done markers
- :mod:`.stages`           simulate, calibrate, discover, features, train, evaluate
- :mod:`.document`         a report as blocks, rendered to Markdown and self-contained HTML
- :mod:`.pipeline_report`  the report's content: fleet, calibration, discrepancy, RUL, figures
- :mod:`.run`              the driver: output checks, lock, stages in order, resume

    from workflows.pipeline import load_config, run_pipeline
    run_pipeline("results", load_config("pipeline.toml"))
"""

from .config import load_config
from .run import run_pipeline

__all__ = ["load_config", "run_pipeline"]
