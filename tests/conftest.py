"""Shared fixtures for the engine_model tests.

The compiled model is built once per test session: the C code is cached on disk (first build
compiles, ~1-2 min; later sessions only tabulate the starting guesses, ~30 s).
"""

from pathlib import Path

import numpy as np
import pytest

from engine_model import EngineModel
from engine_model.physics.atmosphere import t2_from_flight

REPO = Path(__file__).resolve().parents[1]


def load_script(path: Path, name: str):
    """A script of the repository that is not a package module (a benchmark, a docs helper)
    loaded as the module ``name`` and registered in ``sys.modules`` (dataclasses defined in
    it look their module up there)."""
    import importlib.util
    import sys

    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    saved = list(sys.path)  # a script may put its folder first on the path: not for the
    try:                    # rest of the test process (nor the workers it spawns)
        spec.loader.exec_module(module)
    finally:
        sys.path[:] = saved
    return module


def isa_t2_R(alt_ft, mach, dT_isa=0.0):
    """Fan-inlet total temperature [degR] for a flight condition at ISA + ``dT_isa`` [K]."""
    return float(t2_from_flight(float(alt_ft), float(mach), float(dT_isa))) * 1.8


def w_rows(points):
    """(N, 4) array of w = [alt ft, Mach, TRA %, T2 degR] from (alt, Mach, TRA[, dT_isa])
    tuples, T2 from the ISA atmosphere."""
    rows = []
    for pt in points:
        alt, mach, tra = pt[:3]
        dT = pt[3] if len(pt) > 3 else 0.0
        rows.append([alt, mach, tra, isa_t2_R(alt, mach, dT)])
    return np.array(rows, dtype=float)


def reference_csv():
    """The C-MAPSS FD002 early-life operating-point table packaged with hyprog (the tests
    need nothing outside the repository)."""
    from engine_model.analysis.reference import default_reference_path

    return default_reference_path()


@pytest.fixture(scope="session")
def model():
    """The compiled engine model (default design, no effects): the process-wide one that the
    library's own callers share (:func:`engine_model.runtime.shared_model.default_model`)."""
    from engine_model.runtime.shared_model import default_model

    return default_model()


@pytest.fixture(scope="session")
def interpreted_model(model):
    """The same model evaluated by CasADi's virtual machine (no C code)."""
    return EngineModel(design=model.design, compiled=False)


@pytest.fixture(scope="session")
def make_w():
    """``make_w([(alt, Mach, TRA[, dT_isa]), ...])`` -> (N, 4) w with ISA T2 in degR."""
    return w_rows


# ---------------------------------------------------------------------------------------------
# prognostics: synthetic feature tables (no engine model)
# ---------------------------------------------------------------------------------------------

PROGNOSTICS_THETA = ("HPT_eff_mod", "LPT_eff_mod", "LPT_flow_mod")  # ds02's calibration


def synthetic_features(units=(1, 2, 3, 4, 5, 6), test_units=(5, 6), cycles=(18, 30),
                       samples=(8, 14), seed=0):
    """A feature table with every column ``hyprog calibrate`` writes (w, x_s, x_s_hat, x_v,
    x_v_hat, true theta, three ``<q>_hat`` and ``<q>_hat_std``, RUL) and its metadata.

    Each unit lives ``U(cycles)`` cycles of ``U(samples)`` samples; its health ``h = c / EOL``
    moves the sensors and theta, so RUL is learnable; operating conditions are random per
    sample. Returns ``(df, metadata)`` with ``dev_units`` / ``test_units``.
    """
    import pandas as pd

    from engine_model.channels import THETA_NAMES, XS_NAMES, XV_NAMES

    rng = np.random.default_rng(seed)
    frames = []
    for u in units:
        eol = int(rng.integers(cycles[0], cycles[1] + 1))
        for c in range(1, eol + 1):
            m = int(rng.integers(samples[0], samples[1] + 1))
            h = c / eol
            d = {"unit": np.full(m, u), "cycle": np.full(m, c), "t": 10.0 * np.arange(m),
                 "RUL": np.full(m, float(eol - c))}
            d["alt"] = rng.uniform(0.0, 30000.0, m)
            d["Mach"] = rng.uniform(0.2, 0.8, m)
            d["TRA"] = rng.uniform(60.0, 90.0, m)
            d["T2"] = 518.67 - 0.0036 * d["alt"] + 30.0 * d["Mach"] ** 2
            op = d["TRA"] / 90.0 - d["alt"] / 6e4
            for j, s in enumerate(XS_NAMES):
                d[s + "_hat"] = (1 + 0.1 * j) * op + 0.5 * h * (1 + j % 3)
                d[s] = d[s + "_hat"] + rng.normal(0.0, 0.05, m)
            for j, s in enumerate(XV_NAMES):
                d[s] = (1 + 0.2 * j) * op - 0.3 * h
                d[s + "_hat"] = d[s] + rng.normal(0.0, 0.01, m)
            for q in THETA_NAMES:
                d[q] = np.full(m, -0.01 * h * h if q in PROGNOSTICS_THETA else 0.0)
            for q in PROGNOSTICS_THETA:
                d[q + "_hat"] = d[q] + rng.normal(0.0, 5e-4, m)
                d[q + "_hat_std"] = np.full(m, 5e-4)
            frames.append(pd.DataFrame(d))
    df = pd.concat(frames, ignore_index=True)
    meta = {"dev_units": [int(u) for u in units if u not in test_units],
            "test_units": [int(u) for u in test_units]}
    return df, meta


@pytest.fixture(scope="session")
def make_features():
    """``make_features(**kw)`` -> ``(df, metadata)`` of :func:`synthetic_features`."""
    return synthetic_features


@pytest.fixture(scope="session")
def features_parquet(tmp_path_factory):
    """The default synthetic feature table written as hyprog parquet (with its metadata)."""
    from engine_model.datasets import write_parquet

    df, meta = synthetic_features()
    return write_parquet(df, tmp_path_factory.mktemp("features") / "features.parquet", meta)


@pytest.fixture
def torch_one_thread():
    """Torch on one thread for the test (restored after). The tests' networks are tiny, and on
    a shared CPU OpenMP's two spinning threads can be 20x slower than one; bit-identity holds
    for a fixed thread count either way."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
