"""The pipeline's configuration: one TOML file, one table per stage, every option named.

A config file holds any subset of the tables and keys below; what it leaves out takes the
default. A key or table this module does not know is an error naming it and the file (a
misspelt option would otherwise be silently ignored). Values are type-checked; TOML has no
null, so an option whose default is "none" (e.g. ``train.max_rul``) is left out to keep it.

The ``train`` table is derived from the library's :class:`~prognostics.train_config.TrainConfig`
(its fields, types and defaults), so that a training option is written once: every field but
those another table sets (:data:`TRAIN_SET_ELSEWHERE`), with the pipeline's own defaults
where they differ (:data:`TRAIN_PIPELINE_DEFAULTS`) and its own keys (:data:`TRAIN_PIPELINE_KEYS`).
The ``calibrate`` table's ``noise_scale`` and ``prior_std`` take
:class:`~calibration.CalibrationSetup`'s defaults; its ``drift`` default (0.01 per sqrt(hour))
is the pipeline's own: the tiny fleet's ten-flight lives need more drift than the library's
1e-3.

The ``run`` table says how the work is spread, not what is computed: every result is the same
whatever its values (same seeds per unit), so it is in no stage's fingerprint (a resumed run
with other workers skips what is done) and not in ``metrics.json``
(:data:`EXECUTION_TABLES`).

===============  ===================  =========================================================
table            key                  meaning [default]
===============  ===================  =========================================================
``pipeline``     ``seed``             seed of every random draw (discover, validation units,
                                      network initialisation and batch order) [0]
``run``          ``jobs``             worker processes of simulate, calibrate and features
                                      (with ``scheduler = "local"``: the local Dask cluster's
                                      workers) [1]
                 ``scheduler``        send simulate, calibrate and features to a Dask cluster:
                                      its address (``tcp://host:8786``) or ``"local"``
                                      [none: this machine]
``data``         ``units``            units of DATA to use [every unit]
                 ``dev_units``        development units [the metadata's ``dev_units``, else
                                      every unit but the last]
                 ``test_units``       test units [the metadata's ``test_units``, else the last
                                      unit]
                 ``conformal_units``  development units held out to calibrate a split-conformal
                                      interval [none]
``simulate``     ``preset``           with no DATA: simulate this preset (``tiny``, ``ds02``)
                                      instead of using the committed ``data_samples/tiny`` [""]
                 ``rate_hz``          sample rate of the simulation [the preset's]
                 ``seed``             seed of the simulation [0]
                 ``effects``          effects switched on in the simulated truth, as
                                      ``hyprog simulate --effect`` takes them (e.g.
                                      ``"customer_bleed:f0=0.02"``): data with an undeclared
                                      effect for ``discover`` to find [none]
``calibrate``    ``method``           ``ukf``, ``ekf``, ``mhe`` or ``map_cycle`` [ukf]
                 ``params``           health parameters [the paper's three]
                 ``sensors``          measured channels [every x_s in the data]
                 ``drift``            random-walk std of theta per sqrt(hour) [0.01; the tiny
                                      fleet's ten-flight lives need it, README]
                 ``noise_scale``      multiplier of the noise std in R [1.0]
                 ``noise``            ``"model"`` (the simulator's documented noise) or
                                      ``"data"`` (each sensor's noise per operating condition
                                      from the data; ``hyprog calibrate --noise``) [model]
                 ``model_error``      the model's own error, a relative std added to the
                                      noise, or ``"consistent"`` (``hyprog calibrate
                                      --model-error``) [0.0]
                 ``prior_std``        prior std of theta [0.02]
                 ``model_effects``    an adapted model (``hyprog adapt --out FILE``): its
                                      effects are in the model of calibrate and discover;
                                      its SHA-256 is in both stages' fingerprints [""]
``discover``     ``enabled``          run the discrepancy loop [true]
                 ``method``           its warm-start estimator [ukf]
                 ``candidates``       effects to test [the library's steady and sensor effects]
                 ``alpha``            family-wise level [0.01]
                 ``max_effects``      most effects to add [3]
                 ``drift``            ``"mle"`` or a number [mle]
                 ``n_draws``          draws of the family-wise critical value [20000]
                 ``augment``          add what was found and recalibrate (``--augment``) [false]
``train``        ``model``            ``cnn``, ``fnn``, ``dcnn``, the flight models ``tcn``
                                      and ``trend``, or ``similarity`` (no network; inputs
                                      ``["HI_hat_rel"]`` or ``["HI_hat"]``) [cnn]
                 ``inputs``           input sets, each trained and evaluated
                                      [["data-driven", "hybrid"]; ``similarity``:
                                      ``["HI_hat_rel"]``, as ``hyprog train``]
                 ``ensemble``         networks per input set (seeds seed .. seed+N-1) [1]
                 ``epochs``           maximum epochs [6: short, so that the default run takes
                                      a few minutes on 2 cores; the paper's are 30 (CNN) and
                                      60 (FNN)]
                 ``device``           ``cpu``, ``cuda`` or ``auto`` [cpu: the same numbers on
                                      every machine]
                 every other field    of :class:`prognostics.train_config.TrainConfig`, with
                                      its default there: ``window`` [50 CNN / 30 DCNN / 1
                                      FNN / 20 flights tcn and trend / 10 similarity],
                                      ``stride`` [1], ``max_rul`` [no cap],
                                      ``batch_size`` [by data size], ``lr`` [0.001],
                                      ``patience`` [by data size], ``schedule`` [plateau],
                                      ``normalise`` [auto], ``drop_constant`` [true],
                                      ``val_fraction`` [0.1], ``validation`` [auto],
                                      ``val_units`` [none], ``alpha`` (miscoverage of the
                                      conformal interval) [0.1]
===============  ===================  =========================================================
"""

from __future__ import annotations

import copy
import tomllib
import types
import typing
from dataclasses import MISSING, fields
from pathlib import Path

from calibration.base import ESTIMATORS
from calibration.estimation_setup import CalibrationSetup
from engine_model.validation import InputError
from prognostics.choices import LIBRARY_MODELS
from prognostics.train_config import DEFAULT_INPUTS, TrainConfig

_INT, _FLOAT, _STR, _BOOL = int, float, str, bool

_UNITS = "units"  # a list of integers
_NAMES = "names"  # a list of strings

#: TrainConfig fields that another table sets: the seed ([pipeline] seed), the input set (one
#: run per entry of [train] inputs) and the units ([data])
TRAIN_SET_ELSEWHERE = ("seed", "inputs", "units", "test_units", "conformal_units")
#: [train] defaults of the pipeline that differ from TrainConfig's (module docstring)
TRAIN_PIPELINE_DEFAULTS = {"epochs": 6, "device": "cpu"}
#: [train] keys of the pipeline that are not TrainConfig fields
TRAIN_PIPELINE_KEYS = {"inputs": (_NAMES, ["data-driven", "hybrid"]), "ensemble": (_INT, 1)}


def _kind(hint):
    """The schema type of a dataclass field's type hint (``X | None`` as ``X``)."""
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        (hint,) = [a for a in typing.get_args(hint) if a is not type(None)]
    if typing.get_origin(hint) is tuple and typing.get_args(hint)[0] is int:
        return _UNITS
    if hint in (_INT, _FLOAT, _STR, _BOOL):
        return hint
    raise TypeError(f"no config type for {hint!r}")  # pragma: no cover - a new field's type


def _train_schema() -> dict[str, tuple]:
    """The [train] table: TrainConfig's fields in their order, the pipeline's keys after
    ``model``."""
    hints = typing.get_type_hints(TrainConfig)
    schema = {}
    for f in fields(TrainConfig):
        if f.name == "inputs":
            schema.update(TRAIN_PIPELINE_KEYS)
        if f.name in TRAIN_SET_ELSEWHERE:
            continue
        default = f.default if f.default is not MISSING else f.default_factory()
        schema[f.name] = (_kind(hints[f.name]), TRAIN_PIPELINE_DEFAULTS.get(f.name, default))
    return schema


_SETUP = CalibrationSetup()

# table -> key -> (type, default); default None means "not given" (the library's default)
SCHEMA: dict[str, dict[str, tuple]] = {
    "pipeline": {"seed": (_INT, 0)},
    "run": {"jobs": (_INT, 1), "scheduler": (_STR, None)},
    "data": {"units": (_UNITS, None), "dev_units": (_UNITS, None),
             "test_units": (_UNITS, None), "conformal_units": (_UNITS, [])},
    "simulate": {"preset": (_STR, ""), "rate_hz": (_FLOAT, None), "seed": (_INT, 0),
                 "effects": (_NAMES, [])},
    "calibrate": {"method": (_STR, "ukf"), "params": (_NAMES, None),
                  "sensors": (_NAMES, None), "drift": (_FLOAT, 0.01),
                  "noise_scale": (_FLOAT, _SETUP.noise_scale),
                  "noise": (_STR, _SETUP.noise),
                  "model_error": ((_STR, _FLOAT), _SETUP.model_error),
                  "prior_std": (_FLOAT, _SETUP.prior_std), "model_effects": (_STR, "")},
    "discover": {"enabled": (_BOOL, True), "method": (_STR, "ukf"),
                 "candidates": (_NAMES, None), "alpha": (_FLOAT, 0.01),
                 "max_effects": (_INT, 3), "drift": ((_STR, _FLOAT), "mle"),
                 "n_draws": (_INT, 20000), "augment": (_BOOL, False)},
    "train": _train_schema(),
}


def train_config(config: dict, inputs: str, split: dict[str, list[int]],
                 seed: int | None = None) -> TrainConfig:
    """The :class:`TrainConfig` of one input set: the [train] table's TrainConfig fields, the
    seed (``[pipeline] seed`` unless given) and the split's development, test and conformal
    units."""
    c = config["train"]
    kw = {k: c[k] for k in SCHEMA["train"] if k not in TRAIN_PIPELINE_KEYS}
    if kw["val_units"] is not None:
        kw["val_units"] = tuple(kw["val_units"])
    return TrainConfig(**kw, inputs=inputs,
                       seed=config["pipeline"]["seed"] if seed is None else seed,
                       units=tuple(split["dev"]), test_units=tuple(split["test"]),
                       conformal_units=tuple(split["conformal"]))


#: Tables that say how the work runs, not what it computes (module docstring).
EXECUTION_TABLES = ("run",)


def results_config(config: dict) -> dict:
    """``config`` without :data:`EXECUTION_TABLES`: what determines the results."""
    return {t: v for t, v in config.items() if t not in EXECUTION_TABLES}


def check_run(config: dict, source: str = "config") -> None:
    """The ``run`` table's values are usable."""
    if config["run"]["jobs"] < 1:
        raise InputError(f"{source}: [run] jobs must be >= 1, got {config['run']['jobs']}")


def check_values(config: dict, source: str = "config") -> None:
    """Every value of ``config`` usable, checked before any stage runs (a bad value found
    after an hour of calibration wastes the hour), by the library objects that will use them,
    their messages prefixed with ``source: [table]``. What needs the data (units, input
    columns) is checked by the pipeline's data step, also before any stage."""
    from calibration.discrepancy.candidates import check_names
    from calibration.discrepancy.loop import DiscoverOptions
    from engine_model.physics.effects import parse_effect_spec
    from engine_model.simulator.fleet import check_effects, check_rate
    from engine_model.validation import check_seed

    def check(table: str, fn) -> None:
        try:
            fn()
        except InputError as e:
            raise InputError(f"{source}: [{table}] {e}") from None

    check_run(config, source)
    t = config["train"]
    empty = {"dev": [], "test": [], "conformal": []}
    check("train", lambda: train_config(config, "data-driven", empty).resolved())
    if t["ensemble"] < 1:
        raise InputError(f"{source}: [train] ensemble must be >= 1, got {t['ensemble']}")
    if t["model"] in LIBRARY_MODELS and t["ensemble"] > 1:
        raise InputError(f"{source}: [train] ensemble = {t['ensemble']}: the {t['model']} "
                         "model has no network and nothing random; one is the same as many")
    if not t["inputs"]:
        raise InputError(f"{source}: [train] inputs is empty: name at least one input set")
    c = config["calibrate"]
    if c["method"] not in ESTIMATORS:
        raise InputError(f"{source}: [calibrate] method must be one of "
                         f"{', '.join(ESTIMATORS)}, got {c['method']!r}")
    check("calibrate", lambda: calibration_setup(config))
    if not c["drift"] > 0:  # theta's random walk: the discover stage's prior between cycles
        raise InputError(f"{source}: [calibrate] drift must be > 0, got {c['drift']}")
    d = config["discover"]
    if d["augment"] and not d["enabled"]:
        raise InputError(f"{source}: [discover] augment = true with enabled = false: nothing "
                         "is discovered, so nothing would be added; drop one")
    if d["candidates"] is not None:
        check("discover", lambda: check_names(d["candidates"], "candidates"))
    if d["n_draws"] < 1:
        raise InputError(f"{source}: [discover] n_draws must be >= 1, got {d['n_draws']}")
    check("discover", lambda: DiscoverOptions(method=d["method"], alpha=d["alpha"],
                                              max_effects=d["max_effects"], drift=d["drift"],
                                              n_draws=d["n_draws"]))
    sim = config["simulate"]
    given = [k for k, v in (("rate_hz", sim["rate_hz"] is not None), ("seed", sim["seed"] != 0),
                            ("effects", bool(sim["effects"]))) if v]
    if given and not sim["preset"]:
        raise InputError(f"{source}: [simulate] {', '.join(given)} set without preset: with no "
                         "preset nothing is simulated (the pipeline runs on DATA or the "
                         "packaged sample fleet); name the preset or drop them")
    if sim["rate_hz"] is not None:
        check("simulate", lambda: check_rate(sim["rate_hz"]))
    check("simulate", lambda: check_effects([parse_effect_spec(e) for e in sim["effects"]]))
    check("simulate", lambda: check_seed(sim["seed"]))
    dc = config["data"]
    if dc["dev_units"] is not None and dc["test_units"] is not None:
        both = sorted(set(dc["dev_units"]) & set(dc["test_units"]))
        if both:
            raise InputError(f"{source}: [data] unit(s) {', '.join(map(str, both))} are in "
                             "both dev_units and test_units")


def calibration_setup(config: dict):
    """The :class:`~calibration.CalibrationSetup` of the ``calibrate`` table (with
    ``model_error = "consistent"`` its model error is 0 here: the calibrate stage finds it,
    :func:`calibration.consistency.consistent_model_error`)."""
    c = config["calibrate"]
    me = c["model_error"]
    if isinstance(me, str) and me != "consistent":
        raise InputError(f"model_error must be a number or 'consistent', got {me!r}")
    kw = {"drift": c["drift"], "noise_scale": c["noise_scale"], "prior_std": c["prior_std"],
          "noise": c["noise"], "model_error": 0.0 if me == "consistent" else me}
    if c["params"] is not None:
        kw["params"] = tuple(c["params"])
    if c["sensors"] is not None:
        kw["sensors"] = tuple(c["sensors"])
    return CalibrationSetup(**kw)


def defaults() -> dict:
    """The configuration with every default (a fresh copy)."""
    return {t: {k: copy.deepcopy(d) for k, (_, d) in keys.items()} for t, keys in SCHEMA.items()}


def _check_value(where: str, kind, value):
    """``value`` converted to ``kind`` or an InputError naming ``where``."""
    if isinstance(kind, tuple):
        for k in kind:
            try:
                return _check_value(where, k, value)
            except InputError:
                continue
        names = " or ".join(getattr(k, "__name__", str(k)) for k in kind)
        raise InputError(f"{where}: expected {names}, got {value!r}")
    if kind is _BOOL:
        ok = isinstance(value, bool)
    elif kind is _INT:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind is _FLOAT:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        value = float(value) if ok else value
    elif kind is _STR:
        ok = isinstance(value, str)
    elif kind == _UNITS:
        ok = isinstance(value, list) and all(isinstance(v, int) and not isinstance(v, bool)
                                             for v in value)
        if ok and len(set(value)) != len(value):
            raise InputError(f"{where}: a unit is listed twice in {value}")
    elif kind == _NAMES:
        ok = isinstance(value, list) and all(isinstance(v, str) for v in value)
    else:  # pragma: no cover - a schema mistake
        raise TypeError(kind)
    if not ok:
        want = {_UNITS: "a list of integers", _NAMES: "a list of strings"}.get(
            kind, getattr(kind, "__name__", str(kind)))
        raise InputError(f"{where}: expected {want}, got {value!r}")
    return value


def merge(config: dict, given: dict, source: str = "config") -> dict:
    """``config`` updated with the tables of ``given`` (checked against :data:`SCHEMA`)."""
    out = copy.deepcopy(config)
    for table, keys in given.items():
        if table not in SCHEMA:
            raise InputError(f"{source}: unknown table [{table}]; the tables are "
                             f"{', '.join(SCHEMA)}")
        if not isinstance(keys, dict):
            raise InputError(f"{source}: {table} must be a table ([{table}])")
        for key, value in keys.items():
            if key not in SCHEMA[table]:
                raise InputError(f"{source}: unknown key {key!r} in [{table}]; known keys: "
                                 f"{', '.join(SCHEMA[table])}")
            kind = SCHEMA[table][key][0]
            out[table][key] = _check_value(f"{source}: [{table}] {key}", kind, value)
    train = given.get("train", {})
    if "model" in train and "inputs" not in train and out["train"]["model"] in DEFAULT_INPUTS:
        # a model with inputs of its own gets them, as ``hyprog train --model`` does
        out["train"]["inputs"] = [DEFAULT_INPUTS[out["train"]["model"]]]
    check_values(out, source)
    return out


def load_config(path: str | Path | None = None) -> dict:
    """The defaults, overridden by the TOML file ``path`` when given."""
    config = defaults()
    if path is None:
        return config
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such config file")
    if not p.is_file():
        raise InputError(f"{p}: is a directory, expected a TOML config file")
    try:
        given = tomllib.loads(p.read_text())
    except UnicodeDecodeError:
        raise InputError(f"{p}: not a text file") from None
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{p}: not valid TOML ({e})") from None
    return merge(config, given, str(p))


def to_toml(config: dict) -> str:
    """The configuration as TOML (what the report records; options left at "none" are
    written as comments)."""
    lines = []
    for table, keys in config.items():
        lines.append(f"[{table}]")
        for k, v in keys.items():
            lines.append(f"# {k} = (not set)" if v is None else f"{k} = {_toml_value(v)}")
        lines.append("")
    return "\n".join(lines)


def _toml_value(v) -> str:
    import json

    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, float):
        return repr(v)
    return json.dumps(v) if isinstance(v, str) else str(v)
