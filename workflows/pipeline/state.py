"""What a stage depends on and whether its output is already there (resume).

A stage's **fingerprint** is the SHA-256 of what determines its output: the stage's name, its
configuration tables, the fingerprints of the stages it reads and the hyprog version
(:func:`stage_fingerprint`). The data's fingerprint is the SHA-256 of the bytes of every data
file (a parquet directory's part files in path order, or the one h5 file;
:func:`engine_model.datasets.fingerprint.files_fingerprint`), so other data under the same
path are noticed.

A stage writes into its own folder ``OUT/stages/<stage>-<fingerprint[:12]>/`` and, last, a
marker ``stage.json`` (atomically) holding the full fingerprint and the stage's summary. A
stage whose folder has a marker with the same fingerprint is **done** and is skipped; one
without (an interrupted run) is redone in the same folder (a calibration resumes unit by unit
there, a training keeps the models it finished). After a stage completes, the folders of the
same stage with other fingerprints (an earlier configuration) are removed.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

from engine_model.datasets import hyprog_version
from prognostics.outputs import write_json

MARKER = "stage.json"
STAGES_DIR = "stages"


def stage_fingerprint(stage: str, config: dict, inputs: dict) -> str:
    """SHA-256 of the stage name, its ``config`` tables and its ``inputs`` fingerprints."""
    body = {"stage": stage, "config": config, "inputs": inputs, "hyprog": hyprog_version()}
    return hashlib.sha256(json.dumps(body, sort_keys=True, default=str).encode()).hexdigest()


def stage_dir(out: Path, stage: str, fp: str) -> Path:
    return out / STAGES_DIR / f"{stage}-{fp[:12]}"


def done(out: Path, stage: str, fp: str) -> dict | None:
    """The stored summary of ``stage`` when it is done for fingerprint ``fp``, else None."""
    marker = stage_dir(out, stage, fp) / MARKER
    try:
        rec = json.loads(marker.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return rec.get("summary") if rec.get("fingerprint") == fp else None


def mark_done(out: Path, stage: str, fp: str, summary: dict) -> None:
    """Write the marker (last, atomically) and remove the stage's folders of other
    fingerprints. ``OUT/stages/`` is the pipeline's working area: every folder in it is one
    the pipeline made for a stage and a configuration (the report says so), so a folder of a
    configuration that is no longer the stage's is the pipeline's own and is removed."""
    folder = stage_dir(out, stage, fp)
    write_json(folder / MARKER, {"stage": stage, "fingerprint": fp, "summary": summary})
    for other in (out / STAGES_DIR).glob(f"{stage}-*"):
        if other != folder and other.is_dir():
            shutil.rmtree(other, ignore_errors=True)
