"""The adapted model as a file: adapt once, calibrate a whole fleet with it.

``hyprog adapt DATA --out adapted.json`` writes one JSON file (written atomically; an
existing file is replaced only if it is an adapted model, or with ``--overwrite``)::

    {"format": "hyprog-adapted-model", "version": 1,
     "effects": ["design_scaling:component=HPC,eff=-0.0031,flow=0.0042", ...],
     "parameters": [{"candidate", "parameter", "value", "std", "valid", "at_bound"}, ...],
     "channels": [...], "noise": {condition: {channel: std}},
     "data": {"path", "fingerprint", "units", "unit_list", "samples", "early_cycles",
              "model_error", "model_error_shared", "judge", "candidates",
              "engine_folds", "seed"},
     "selection": {...}, "seconds": ..., "hyprog_version": "..."}

(records written before a key existed lack it; :func:`calibration.adaptation.assess` reads
a missing ``model_error`` as the noise alone, with which those records were fitted, and a
missing ``model_error_shared`` as the error counted per sample). A
number that could not be computed (no converged sample at a condition) is written as
``null``: the file is strict JSON.

``effects`` are effect specifications (:func:`engine_model.physics.effects.parse_effect_spec`)
held at the fitted values: the model that ``calibrate``, ``discover`` and ``pipeline`` build
with ``--model-effects FILE`` (:func:`load_adapted`). Every feature table calibrated with it
records the effects and the file's SHA-256 in its metadata (``calibration.effects``,
``calibration.model_effects``). A file whose effects would change nothing (none, or every
size at its neutral default), a series effect (``dynamics``: calibration evaluates the steady
model) or an effect given twice is refused when read.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

from engine_model.datasets.jsonable import jsonable
from engine_model.physics.effect_base import EffectSet
from engine_model.physics.effects import EffectSpecError, parse_effect_spec
from engine_model.runtime.atomic import atomic_output
from engine_model.runtime.ownership import OutputKind
from engine_model.validation import InputError

FORMAT = "hyprog-adapted-model"
VERSION = 1


def is_adapted_model(path: Path) -> bool:
    """``path`` is a file this module wrote (its JSON names the format)."""
    try:
        return path.is_file() and json.loads(path.read_text()).get("format") == FORMAT
    except (OSError, ValueError, AttributeError):
        return False


ADAPTED_MODEL = OutputKind("a hyprog adapted model", directory=False, ours=is_adapted_model)


@dataclass
class AdaptedModel:
    """An adapted model (module docstring): ``effects`` (specifications), ``record`` (the
    whole JSON document), ``path`` and ``sha256`` of the file it was read from."""

    effects: list
    record: dict = field(default_factory=dict)
    path: str | None = None
    sha256: str | None = None

    def provenance(self) -> dict:
        """What a feature table records about the model it was calibrated with."""
        return {"file": self.path, "sha256": self.sha256, "effects": list(self.effects),
                "data": self.record.get("data", {})}


def write_adapted(record: dict, out: Path, overwrite: bool = False, inputs=()) -> Path:
    """Write ``record`` (with ``format``/``version`` set) to ``out`` atomically."""
    body = {"format": FORMAT, "version": VERSION, **record}
    with atomic_output(out, ADAPTED_MODEL, overwrite, inputs) as tmp:
        tmp.write_text(json.dumps(jsonable(body), indent=1, allow_nan=False) + "\n")
    return Path(out)


def load_adapted(path) -> AdaptedModel:
    """Read and check an adapted model; a clear error naming the file otherwise."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise InputError(f"{p}: cannot read the adapted model ({exc.strerror})") from None
    try:
        doc = json.loads(raw)
    except ValueError as exc:
        raise InputError(f"{p}: not an adapted model (not JSON: {exc.msg} at line "
                         f"{exc.lineno})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise InputError(f"{p}: not an adapted model (no \"format\": \"{FORMAT}\"; write one "
                         "with hyprog adapt)")
    if doc.get("version") != VERSION:
        raise InputError(f"{p}: adapted model version {doc.get('version')!r}, this hyprog "
                         f"reads version {VERSION}")
    effects = doc.get("effects")
    if not isinstance(effects, list) or not all(isinstance(e, str) for e in effects):
        raise InputError(f"{p}: \"effects\" must be a list of effect specifications")
    if not effects:
        raise InputError(f"{p}: the adapted model holds no effect: calibrating with it is "
                         "calibrating the model as designed (leave --model-effects out)")
    for i, spec in enumerate(effects):
        try:
            e = parse_effect_spec(spec)
        except (EffectSpecError, InputError) as exc:
            raise InputError(f"{p}: effects[{i}]: {exc}") from None
        if e.series:
            raise InputError(f"{p}: effects[{i}]: {spec} is a series effect (it acts on a "
                             "flight's time series); an adapted model changes the steady "
                             "model, which is all calibrate evaluates")
        if e.is_neutral():
            raise InputError(f"{p}: effects[{i}]: {spec}: every parameter is at its neutral "
                             "default, so the effect changes nothing")
    try:
        EffectSet([parse_effect_spec(s) for s in effects])
    except InputError as exc:  # an effect given twice
        raise InputError(f"{p}: {exc}") from None
    return AdaptedModel(list(effects), doc, str(p), hashlib.sha256(raw).hexdigest())
