"""Shared fixtures for the engine_model tests.

The compiled model is built once per test session: the C code is cached on disk (first build
compiles, ~1-2 min; later sessions only tabulate the starting guesses, ~30 s).
"""

from pathlib import Path

import numpy as np
import pytest

from engine_model import EngineModel
from engine_model.atmosphere import t2_from_flight

REPO = Path(__file__).resolve().parents[1]
REFERENCE_NAME = "cmapss-fd002-operating-points.csv"


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
    """The C-MAPSS FD002 early-life operating-point table: the repository's own copy
    (data_samples/) if present, else shared/reference/ found by walking up from tests/."""
    own = REPO / "data_samples" / REFERENCE_NAME
    if own.is_file():
        return own
    for parent in Path(__file__).resolve().parents:
        cand = parent / "shared" / "reference" / REFERENCE_NAME
        if cand.is_file():
            return cand
    return None


@pytest.fixture(scope="session")
def model():
    """The compiled engine model (default design, no effects): the process-wide one that the
    library's own callers share (:func:`engine_model.shared_model.default_model`)."""
    from engine_model.shared_model import default_model

    return default_model()


@pytest.fixture(scope="session")
def interpreted_model(model):
    """The same model evaluated by CasADi's virtual machine (no C code)."""
    return EngineModel(design=model.design, compiled=False)


@pytest.fixture(scope="session")
def make_w():
    """``make_w([(alt, Mach, TRA[, dT_isa]), ...])`` -> (N, 4) w with ISA T2 in degR."""
    return w_rows
