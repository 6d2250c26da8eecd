"""A dataset's metadata: a JSON object stored with the table, written byte-for-byte
deterministically.

Metadata (a JSON-serialisable dict, unknown keys kept)
------------------------------------------------------
``preset`` (str), ``seed`` (int), ``effects`` (list of ``{"name": str, "params": dict}``),
``sample_rate_hz`` (float; ``sample_rate`` is accepted when reading), ``hyprog_version``
(filled in on write when absent), ``dev_units`` / ``test_units`` (lists of int), and
``source_format`` (``"ncmapss-h5"``, set by :func:`~.ncmapss_h5.read_ncmapss_h5`;
``"cmapss-text"``, set by :func:`~.cmapss.read_cmapss`). Nothing time-dependent is added, so
the same table and metadata give the same bytes.

Types are checked when metadata is read or written (:func:`check_metadata`): ``dev_units`` /
``test_units`` must be lists of integers, ``effects`` a list of names or of ``{"name",
"params"}`` objects, or an object of name: params (params an object), the sample rate a
finite number > 0; anything else is an InputError naming the file and the key.

Where it is stored: under the key ``META_KEY`` (``"hyprog"``) of every parquet part file's
Arrow schema metadata, and as the root attribute of that name of an h5 file.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..validation import InputError
from .jsonable import json_default

META_KEY = "hyprog"  # parquet schema-metadata key and h5 root attribute
SAMPLE_RATE_KEY = "sample_rate_hz"


def metadata_json(metadata: Mapping[str, Any] | None, source: str) -> str:
    """Metadata as canonical JSON (sorted keys, no whitespace): the same dict, the same bytes."""
    try:
        return json.dumps(dict(metadata or {}), default=json_default, sort_keys=True,
                          separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{source}: metadata is not JSON-serialisable ({exc})") from None


def hyprog_version() -> str:
    """The installed hyprog version, ``"unknown"`` in a source checkout that is not
    installed (the value a writer records under ``hyprog_version``)."""
    try:
        from importlib.metadata import version

        return version("hyprog")
    except Exception:  # not installed (a source checkout on sys.path)
        return "unknown"


def metadata_for_write(metadata: Mapping[str, Any] | None, source: str) -> dict[str, Any]:
    """The metadata a writer stores: a JSON round trip of ``metadata`` (so it is plain JSON
    data) with ``hyprog_version`` filled in when absent."""
    meta = json.loads(metadata_json(metadata, source))
    if not isinstance(meta, dict):
        raise InputError(f"{source}: metadata must be a dict")
    check_metadata(meta, source)
    meta.setdefault("hyprog_version", hyprog_version())
    return meta


def parse_metadata(raw: bytes | str | None, source: str) -> dict[str, Any]:
    """The stored metadata JSON as a dict (``{}`` when there is none), its types checked
    (:func:`check_metadata`)."""
    if raw is None:
        return {}
    try:
        meta = json.loads(raw)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{source}: the '{META_KEY}' metadata is not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise InputError(f"{source}: the '{META_KEY}' metadata is not a JSON object")
    check_metadata(meta, source)
    return meta


def unit_list(meta: Mapping[str, Any] | None, key: str, source: str) -> list[int] | None:
    """The metadata's list of units under ``key`` (``dev_units``, ``test_units``), None when
    absent; anything but a list (or tuple) of unit numbers is an InputError naming ``source``
    and the key."""
    listed = (meta or {}).get(key)
    if listed is None:
        return None
    if not isinstance(listed, (list, tuple)) or not all(
            isinstance(u, (int, np.integer)) and not isinstance(u, bool) for u in listed):
        raise InputError(f"{source}: metadata {key} must be a list of unit numbers, got "
                         f"{listed!r:.60}")
    return [int(u) for u in listed]


def _effects_ok(v: Any) -> bool:
    """``effects`` absent, a list of names or ``{"name", "params"}`` objects, or an object of
    name: params, every params an object (or absent)."""
    if v is None:
        return True
    if isinstance(v, dict):
        return all(p is None or isinstance(p, dict) for p in v.values())
    if isinstance(v, list):
        return all(isinstance(e, str) or (isinstance(e, dict) and (
            e.get("params") is None or isinstance(e.get("params"), dict))) for e in v)
    return False


def check_metadata(meta: Mapping[str, Any], source: str) -> None:
    """The known keys hold what readers use them as (module doc); an InputError names
    ``source`` and the key otherwise. Keys absent or None are not checked."""
    for key in ("dev_units", "test_units"):
        unit_list(meta, key, source)
    if not _effects_ok(meta.get("effects")):
        v = meta.get("effects")
        raise InputError(f"{source}: metadata effects must be a list of names or"
                         ' {"name", "params": {...}} objects, or an object of name: params,'
                         f" got {json.dumps(v)[:60]}")
    for key in (SAMPLE_RATE_KEY, "sample_rate"):
        v = meta.get(key)
        if v is not None and not (isinstance(v, (int, float)) and not isinstance(v, bool)
                                  and math.isfinite(v) and v > 0):
            raise InputError(f"{source}: metadata {key} must be a finite number > 0 [Hz],"
                             f" got {json.dumps(v)[:60]}")


def sample_rate(meta: Mapping[str, Any], default: float | None = None) -> float | None:
    """The metadata's sample rate [Hz] (``sample_rate_hz``, or the older ``sample_rate``)."""
    for key in (SAMPLE_RATE_KEY, "sample_rate"):
        if meta.get(key) is not None:
            return float(meta[key])
    return default
