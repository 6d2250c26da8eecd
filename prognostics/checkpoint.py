"""Saving and loading a :class:`ensemble.RulModel`: safetensors + JSON, hashed, never a pickle.

Layout of a model directory::

    MODEL_DIR/model.json               manifest (below)
    MODEL_DIR/member-<seed>.safetensors  the weights of one network (tensors only)
    MODEL_DIR/library.safetensors      the similarity model's library (no members)

``model.json`` holds ``format`` (``"hyprog-prognostics"``), ``format_version``,
``hyprog_version``, the training ``config`` (model, inputs, window, stride, ``max_rul``,
seeds, units ...), the input ``columns``, the ``scaler`` (minimum / maximum per column), the
``conformal`` interval (or null), ``trained_with`` (torch's version, the device and torch's
thread count: what the bits of a run depend on besides seed and data, :mod:`.training`; null
in a model written before it was recorded), ``units`` (the development units of each role in
training, ``training`` / ``validation`` / ``conformal``: evaluating one of them warns; null
in a model written before they were recorded) and per member its file, ``sha256``, seed, best
epoch, parameter count and training history; ``library`` (null for a network): the
similarity model's file (arrays ``hi``, ``rul``, ``lengths``:
:meth:`.similarity.SimilarityRul.to_arrays`), its ``sha256`` and bandwidth ``sigma2`` (the
library's health index is the model's one input column); then ``sha256``: the SHA-256 of
the canonical JSON (sorted keys, no spaces) of everything else in the manifest.

Loading refuses, with an :class:`InputError` naming the file:

- a directory without ``model.json``, a manifest that is not JSON or has another ``format``
  (a foreign file);
- a manifest whose own ``sha256`` does not match (edited by hand, truncated) or a weights file
  whose SHA-256 is not the one recorded (tampered, swapped between models);
- another ``format_version`` (the layout changed; retrain or use the hyprog that wrote it);
- weights whose names or shapes do not fit the recorded network (checked on a network built
  on PyTorch's ``meta`` device, before any memory is allocated for it);
- a library (the similarity model's) whose arrays do not describe units, a library on a
  network's manifest or networks on a library model's.

**What the hashes do not do.** The SHA-256 values are unkeyed checksums: they catch accidents
(a truncated copy, a hand edit, weights swapped between models), not an adversary, who can
edit ``model.json`` and recompute its hash. Nothing in a model directory is executed
(safetensors and JSON, no pickle), and a manifest that does not describe its weights is
refused, so an edited one cannot make hyprog run code or allocate without bound; but a
consistent edit (another scaler, another conformal quantile) loads. Keep models where only
trusted people write, or sign the directory with an external tool.

A model written by another hyprog *version* with the same ``format_version`` loads, with a
``UserWarning`` naming both versions: the format is versioned on its own, so a version bump
that does not touch it does not strand trained models, but the user hears about it.

Safetensors (Hugging Face) stores raw tensors and a JSON header; reading it executes no code,
unlike ``torch.load`` of a pickle. Writing is atomic (:mod:`engine_model.runtime.atomic`):
the directory is built as a hidden temporary sibling and renamed into place, only after the
new one is complete. An existing target is replaced by the ownership rule
(:mod:`engine_model.runtime.ownership`, kind :data:`MODEL_DIRECTORY`): an empty directory or a
hyprog model directory (its ``model.json`` is a manifest of this format) holding nothing but
the manifest and the weights files it names; anything else, a user's ``NOTES.md`` in the model
folder included, only with ``overwrite`` (``--overwrite``); never what the command reads.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

from safetensors import SafetensorError
from safetensors.torch import load as st_load
from safetensors.torch import save as st_save

from engine_model.datasets import hyprog_version
from engine_model.runtime.atomic import atomic_output
from engine_model.runtime.ownership import OutputKind, check_output
from engine_model.validation import InputError

from .conformal import SplitConformal
from .scaling import scaler_from_dict
from .train_config import LIBRARY_MODELS, TrainConfig
from .training import Member

if TYPE_CHECKING:  # ensemble imports this module
    from .ensemble import RulModel

FORMAT = "hyprog-prognostics"
FORMAT_VERSION = 2  # 2: size-rule config fields, per-condition scaler, dropped columns
MANIFEST = "model.json"
LIBRARY_FILE = "library.safetensors"


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _canonical(obj) -> bytes:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()


def _manifest(model) -> tuple[dict, dict[str, bytes]]:
    files, members = {}, []
    for m in model.members:
        name = f"member-{m.seed}.safetensors"
        if name in files:
            raise InputError(f"two members with seed {m.seed}")
        blob = st_save({k: v.contiguous() for k, v in m.state.items()},
                       metadata={"format": FORMAT})
        files[name] = blob
        members.append({"file": name, "sha256": sha256_bytes(blob), "seed": m.seed,
                        "best_epoch": m.best_epoch, "parameters": m.parameters,
                        "history": m.history})
    library = None
    if model.library is not None:
        import torch

        blob = st_save({k: torch.from_numpy(v) for k, v in model.library.to_arrays().items()},
                       metadata={"format": FORMAT})
        files[LIBRARY_FILE] = blob
        library = {"file": LIBRARY_FILE, "sha256": sha256_bytes(blob),
                   "sigma2": model.library.sigma2}  # its column: the model's one input
    body = {"format": FORMAT, "format_version": FORMAT_VERSION,
            "hyprog_version": model.info.get("hyprog_version", hyprog_version()),
            "config": model.config.to_dict(), "columns": list(model.columns),
            "scaler": model.scaler.to_dict(),
            "dropped_constant": list(model.info.get("dropped_constant", [])),
            "health_effects": list(model.info.get("health_effects", [])),
            "units": model.info.get("units"),
            "conformal": None if model.conformal is None else model.conformal.to_dict(),
            "trained_with": model.info.get("trained_with"),
            "members": members, "library": library}
    body["sha256"] = sha256_bytes(_canonical(body))
    return body, files


def _manifest_of(path: Path) -> dict | None:
    """The manifest of the directory ``path`` when it is one of this format, else None."""
    try:
        body = json.loads((path / MANIFEST).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return body if isinstance(body, dict) and body.get("format") == FORMAT else None


def is_model_directory(path: Path) -> bool:
    """``path`` is a model directory hyprog wrote (its ``model.json`` is a manifest of this
    format): what :func:`save_model` may replace."""
    return _manifest_of(path) is not None


def model_layout(path: Path) -> list[str]:
    """The files hyprog wrote in the model directory ``path``: the manifest and the weights
    (or library) files it names."""
    body = _manifest_of(path) or {}
    members = body.get("members")
    names = [m.get("file") for m in members if isinstance(m, dict)] \
        if isinstance(members, list) else []
    if isinstance(body.get("library"), dict):
        names.append(body["library"].get("file"))
    return [MANIFEST, *(n for n in names if isinstance(n, str) and n and Path(n).name == n)]


#: A model directory (the ownership rule's kind, module docstring).
MODEL_DIRECTORY = OutputKind("a hyprog model directory", directory=True,
                             ours=is_model_directory, layout=model_layout)


def check_model_target(path: str | os.PathLike, overwrite: bool = False,
                       inputs=()) -> Path:
    """``path`` may receive a model directory (module docstring; ``inputs``: what the command
    reads). Call it before a long training so that a bad ``--out`` fails first, not after
    hours."""
    return check_output(path, MODEL_DIRECTORY, overwrite, inputs)


def save_model(model, path: str | os.PathLike, overwrite: bool = False, inputs=()) -> Path:
    """Write ``model`` to the directory ``path`` atomically (module docstring)."""
    body, files = _manifest(model)
    with atomic_output(path, MODEL_DIRECTORY, overwrite, inputs) as tmp:
        for name, blob in files.items():
            (tmp / name).write_bytes(blob)
        (tmp / MANIFEST).write_text(json.dumps(body, indent=1, allow_nan=False) + "\n")
    return Path(path)


def _read_manifest(directory: Path) -> dict:
    file = directory / MANIFEST
    if not file.is_file():
        raise InputError(f"{directory}: not a hyprog model directory (no {MANIFEST})")
    try:
        body = json.loads(file.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise InputError(f"{file}: not a hyprog model manifest (not JSON)") from None
    if not isinstance(body, dict) or body.get("format") != FORMAT:
        raise InputError(f"{file}: not a hyprog model manifest (format is not {FORMAT!r})")
    recorded = body.pop("sha256", None)
    try:
        actual = sha256_bytes(_canonical(body))
    except (TypeError, ValueError):
        actual = None
    if recorded != actual:
        raise InputError(f"{file}: SHA-256 mismatch: the manifest was modified or is "
                         "corrupt; refusing to load")
    if body.get("format_version") != FORMAT_VERSION:
        raise InputError(f"{file}: model format version {body.get('format_version')} (written "
                         f"by hyprog {body.get('hyprog_version')}); this hyprog reads version "
                         f"{FORMAT_VERSION}: retrain the model")
    return body


def _load_tensors(directory: Path, entry, what: str, record: str) -> tuple[dict, Path]:
    """The tensors of the manifest's ``record`` (``member``, ``library``) ``entry``, whose
    file holds ``what`` (``weights``, ``library``), checked against its SHA-256."""
    if not isinstance(entry, dict):
        raise InputError(f"{directory / MANIFEST}: malformed {record} record")
    name = str(entry.get("file", ""))
    file = directory / name
    if not name or Path(name).name != name or not file.is_file():
        raise InputError(f"{file}: {what} file missing")
    blob = file.read_bytes()
    if sha256_bytes(blob) != entry.get("sha256"):
        raise InputError(f"{file}: SHA-256 mismatch: the {what} file was modified or does not "
                         "belong to this model; refusing to load")
    try:
        return st_load(blob), file
    except (SafetensorError, ValueError) as exc:
        raise InputError(f"{file}: unreadable safetensors file ({exc})") from None


def _load_library(directory: Path, entry, window: int, column: str):
    """The similarity model's library of the manifest's record ``entry``."""
    from .similarity import SimilarityRul

    arrays, file = _load_tensors(directory, entry, "library", "library")
    try:
        return SimilarityRul.from_arrays({k: v.numpy() for k, v in arrays.items()},
                                         float(entry["sigma2"]), window, column,
                                         source=str(file))
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{directory / MANIFEST}: malformed library record ({exc})") from None


def _load_member(directory: Path, entry) -> Member:
    """One member of the manifest: its weights file checked against the recorded SHA-256."""
    state, _ = _load_tensors(directory, entry, "weights", "member")
    try:
        return Member(int(entry["seed"]), state, list(entry.get("history", [])),
                      int(entry.get("best_epoch", 0)), int(entry.get("parameters", 0)))
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{directory / MANIFEST}: malformed member record ({exc})") from None


def _check_shapes(manifest: Path, config: TrainConfig, n_inputs: int, members) -> None:
    """The members' weights have the shapes of the network the manifest describes, checked on
    a network built on PyTorch's ``meta`` device (shapes without memory), so that an edited
    manifest (a window of 1e9) is refused before a real network is allocated."""
    import torch

    from .models import build_model

    with torch.device("meta"):
        skeleton = build_model(config.model, n_inputs, config.window)
    want = {k: tuple(v.shape) for k, v in skeleton.state_dict().items()}
    for m in members:
        got = {k: tuple(v.shape) for k, v in m.state.items()}
        if got != want:
            diff = sorted(k for k in set(want) | set(got) if want.get(k) != got.get(k))
            raise InputError(f"{manifest}: the weights do not fit a {config.model} with window "
                             f"{config.window} and {n_inputs} inputs ({diff[0]}: weights "
                             f"{got.get(diff[0])}, network {want.get(diff[0])}); the manifest "
                             "does not describe these weights")


def load_model(path: str | os.PathLike) -> RulModel:
    """Read a model directory (or its ``model.json``) -> :class:`ensemble.RulModel`."""
    from .ensemble import RulModel

    p = Path(path)
    if p.is_file() and p.name == MANIFEST:
        p = p.parent
    if not p.exists():
        raise InputError(f"{p}: no such model directory")
    if not p.is_dir():
        raise InputError(f"{p}: not a hyprog model directory (a file)")
    body = _read_manifest(p)
    version = body.get("hyprog_version")
    if version != hyprog_version():
        warnings.warn(f"{p}: model written by hyprog {version}, this is hyprog "
                      f"{hyprog_version()} (same format version {FORMAT_VERSION})",
                      UserWarning, stacklevel=2)
    try:
        config = TrainConfig.from_dict(body["config"]).resolved()
        columns = tuple(str(c) for c in body["columns"])
        scaler = scaler_from_dict(body["scaler"])
        dropped = [str(c) for c in body.get("dropped_constant", [])]
        effects = [str(e) for e in body.get("health_effects", [])]
        used = body.get("units")  # the units of each role in training (None: not recorded)
        used = None if used is None else {str(k): [int(u) for u in v] for k, v in used.items()}
        conformal = None if body["conformal"] is None else \
            SplitConformal.from_dict(body["conformal"])
        entries = list(body["members"])
        library = body.get("library")
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise InputError(f"{p / MANIFEST}: malformed manifest ({e})") from None
    if scaler.columns != columns:
        raise InputError(f"{p / MANIFEST}: the scaler's columns differ from the inputs")
    is_library = config.model in LIBRARY_MODELS
    if is_library != (library is not None) or (is_library and (entries or len(columns) != 1)):
        raise InputError(f"{p / MANIFEST}: a {config.model} model with "
                         f"{'a' if library is not None else 'no'} library, {len(entries)} "
                         f"network(s) and {len(columns)} input(s): the manifest does not "
                         "describe this model")
    if not is_library and not entries:
        raise InputError(f"{p / MANIFEST}: no trained members")
    members = [_load_member(p, e) for e in entries]
    if members:
        _check_shapes(p / MANIFEST, config, len(columns), members)
    model = RulModel(config, columns, scaler, members, conformal,
                     info={"hyprog_version": version, "path": str(p),
                           "dropped_constant": dropped, "health_effects": effects,
                           "units": used, "trained_with": body.get("trained_with")},
                     library=None if library is None else
                     _load_library(p, library, config.window, columns[0]))
    model.networks()  # weights must fit the recorded network
    return model
