"""Work batched over units gives each unit the numbers it gets alone, bit for bit.

``hyprog calibrate`` on a fleet of many short units (C-MAPSS: 100 units of about 200 cycles)
batches what used to be one model call per unit: the checks of the data against the model
(:func:`calibration.unit_check.check_units_many`), the observability check
(:func:`calibration.observability.check_observability_many`), both on
``EngineModel.solve_series(..., starts=...)``; the model's batched evaluations go through
CasADi's buffer interface (:mod:`engine_model.solver.batch_eval`); the compiled libraries are
found without building the sensitivities (:func:`engine_model.solver.codegen.compile_keyed`).
Each test compares the batched result with the one-unit-at-a-time one exactly (``==``, not a
tolerance), and errors come in the order one unit at a time gives them.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from calibration import CalibrationSetup
from calibration.calibrate_fleet import calibrate_fleet, features_of
from calibration.observability import check_observability, check_observability_many
from calibration.series import early_samples, prepare_unit
from calibration.unit_check import check_units, check_units_many
from engine_model import InputError, datasets
from tests.conftest import REPO

TINY = REPO / "data_samples" / "tiny"
SETUP = CalibrationSetup(drift=0.01)


@pytest.fixture(scope="module")
def units():
    """Units 1-3 of the tiny fleet (their first flights: lengths that are and are not
    multiples of solve_series' anchor spacing), as DataFrames."""
    df, meta = datasets.read_dataset(TINY, units=[1, 2, 3])
    df = df[df["cycle"] <= 2]
    return [g.reset_index(drop=True) for _, g in df.groupby("unit")], meta


def _same(a, b):
    assert a.shape == b.shape and np.array_equal(a, b, equal_nan=True)


def test_solve_series_of_stacked_series_equals_one_call_each(model, units):
    frames, _ = units
    ws = [f[["alt", "Mach", "TRA", "T2"]].to_numpy(float)[:n]
          for f, n in zip(frames, (130, 64, 7), strict=True)]
    th = np.zeros((sum(map(len, ws)), 10))
    th[:, 0] = -0.01
    starts = np.cumsum([0] + [len(w) for w in ws[:-1]])
    both = model.solve_series(np.concatenate(ws), th, starts=starts)
    for w, a in zip(ws, starts, strict=True):
        alone = model.solve_series(w, th[: len(w)])
        sl = slice(a, a + len(w))
        _same(both.x[sl], alone.x)
        _same(both.converged[sl], alone.converged)
        _same(both.iterations[sl], alone.iterations)
    with pytest.raises(InputError, match="starts"):
        model.solve_series(ws[0], th[: len(ws[0])], starts=[1])


def test_observability_of_many_units_equals_one_unit_at_a_time(model, units):
    frames, meta = units
    for setup in (SETUP.for_dataset(meta),
                  CalibrationSetup(sensors=("P2", "P15"), drift=0.01)):
        series = [prepare_unit(f, setup) for f in frames]
        with warnings.catch_warnings(record=True) as w_many:
            warnings.simplefilter("always")
            many = check_observability_many(model, series, setup)
        with warnings.catch_warnings(record=True) as w_one:
            warnings.simplefilter("always")
            one = [check_observability(model, s, setup) for s in series]
        assert [str(w.message) for w in w_many] == [str(w.message) for w in w_one]
        for a, b in zip(many, one, strict=True):
            _same(a.fisher, b.fisher)
            assert (a.observable, a.unobservable, a.rank, a.data_std) == (
                b.observable, b.unobservable, b.rank, b.data_std)
    assert w_one  # the second setup leaves a parameter unobservable: warned per unit


def test_observability_batches_are_bounded_and_change_no_number(model, units, monkeypatch):
    import calibration.observability as obs

    frames, meta = units
    setup = SETUP.for_dataset(meta)
    series = [prepare_unit(f, setup) for f in frames]
    whole = check_observability_many(model, series, setup)
    real, batches = obs._fisher_batch, []

    def spy(model, batch_series, setup, rows, *rest):
        batches.append([len(r) for r in rows])
        return real(model, batch_series, setup, rows, *rest)

    monkeypatch.setattr(obs, "_fisher_batch", spy)
    sizes = [len(obs.sample_rows(len(s), setup)) for s in series]
    for limit in (1, sizes[0] + sizes[1]):  # one unit a batch; the first two together
        batches.clear()
        monkeypatch.setattr(obs, "OBSERVABILITY_BATCH_POINTS", limit)
        for a, b in zip(check_observability_many(model, series, setup), whole, strict=True):
            _same(a.fisher, b.fisher)
        assert sum(batches, []) == sizes  # every unit once, whole, in order
        assert all(len(b) == 1 or sum(b) <= limit for b in batches), batches
    assert batches[0] == sizes[:2]


def test_batched_evaluation_equals_casadi_call(model):
    """The buffer interface returns what calling the mapped Function and converting its DMs
    gives, padding and sparse outputs (the sensitivities' structural zeros) included."""
    rng = np.random.default_rng(3)
    n = 13
    w = np.column_stack([rng.uniform(0, 30000, n), rng.uniform(0.2, 0.8, n),
                         rng.uniform(70, 90, n), rng.uniform(450, 500, n)])
    th = rng.normal(0, 0.01, (n, 10))
    x = model.solve(w, th).x
    cols = model._columns(x, w, th, None)
    for key in ("outputs", "sens", "resjac"):
        f = model._eval.functions[key].map(n, "serial")
        outs = f(*cols)
        outs = outs if isinstance(outs, (list, tuple)) else [outs]
        for got, ref in zip(model._eval(key, *cols), outs, strict=True):
            _same(got, np.asarray(ref))
    assert not model._eval.functions["sens"].sparsity_out(0).is_dense()


def _kelvin(frame: pd.DataFrame) -> pd.DataFrame:
    out = frame.copy()
    for c in ("T24", "T30", "T50"):
        out[c] = out[c] / 1.8
    return out


def test_unit_checks_of_many_units_are_one_unit_at_a_time(model, units):
    frames, meta = units
    setup = SETUP.for_dataset(meta)
    series = [prepare_unit(f, setup) for f in frames]
    many = check_units_many(model, [early_samples(s, 50) for s in series], setup)
    assert [[c.channel for c in checks] for checks in many] == [
        [c.channel for c in check_units(model, s, setup, n_check=50)] for s in series]
    bad = [series[0], prepare_unit(_kelvin(frames[1]), setup),
           prepare_unit(_kelvin(frames[2]), setup)]
    with pytest.raises(InputError, match=r"unit 2: columns T24, T30, T50 look like K"):
        check_units_many(model, bad, setup)


def test_a_fleet_reports_the_first_bad_unit_whatever_the_batching(model, units, tmp_path):
    """Unit 2 in K, unit 3 with a NaN: the model check of unit 2 is reported, as one unit at
    a time did, although unit 3 is read before the batch of checks runs."""
    frames, meta = units
    f3 = frames[2].copy()
    f3.loc[3, "T30"] = np.nan
    df = pd.concat([frames[0], _kelvin(frames[1]), f3], ignore_index=True)
    with pytest.raises(InputError, match="unit 2: columns T24, T30, T50 look like K"):
        calibrate_fleet(df, "ukf", SETUP, out=tmp_path / "f")
    assert not (tmp_path / "f").exists() or not datasets.written_units(tmp_path / "f")


def test_fleet_features_equal_each_unit_calibrated_alone(model, units):
    """The feature table of a fleet run (checks and observability batched over its units,
    the filter in lockstep) equals each unit's run alone, every column bit for bit."""
    frames, meta = units
    df = pd.concat(frames, ignore_index=True)
    fleet = features_of(calibrate_fleet(df, "ukf", SETUP))
    for f in frames:
        u = int(f["unit"].iloc[0])
        alone = features_of(calibrate_fleet(f, "ukf", SETUP))
        mine = fleet[fleet["unit"] == u].reset_index(drop=True)
        pd.testing.assert_frame_equal(mine, alone, check_exact=True)


def test_a_cached_model_is_loaded_without_building_its_sensitivities(model):
    from engine_model.solver.model import EngineModel

    again = EngineModel()  # libraries and table in the cache (the fixture built them)
    assert again._derived_functions == {}
    _same(again.outputs_at(np.zeros((1, 8)) + 1, np.array([[0, 0, 100, 518.67]])),
          model.outputs_at(np.zeros((1, 8)) + 1, np.array([[0, 0, 100, 518.67]])))


def test_an_interpreted_model_builds_the_sensitivities_only_when_asked(model):
    """CasADi's virtual machine solves with the Newton Jacobian alone; the sensitivities'
    graph (about 2 s) is built on the first call that needs it, without the guess table's
    ``dxdth``, and gives the compiled model's numbers."""
    from engine_model.solver.model import EngineModel

    vm = EngineModel(compiled=False)
    w = np.array([[10000.0, 0.5, 80.0, 500.0], [0.0, 0.0, 90.0, 518.67]])
    th = np.zeros((2, 10))
    res = vm.solve_series(w, th, vm.p_matrix(None, 2))
    assert res.converged.all()
    vm.outputs_at(res.x, w, th)
    assert set(vm._derived_functions) == {"resjac"}
    s, ref = vm.sensitivities_at(res.x, w, th), model.sensitivities_at(res.x, w, th)
    assert set(vm._derived_functions) == {"resjac", "sens"}
    np.testing.assert_allclose(s.theta, ref.theta, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(s.w, ref.w, rtol=1e-9, atol=1e-9)


def test_keyed_compile_builds_only_on_a_miss(tmp_path, monkeypatch):
    import casadi as ca

    from engine_model.solver.codegen import compile_keyed

    monkeypatch.setenv("HYPROG_CACHE", str(tmp_path))
    calls = []

    def build():
        calls.append(1)
        x = ca.SX.sym("x")
        return [ca.Function("keyed_square", [x], [x * x])]

    for _ in range(2):
        fns = compile_keyed("hyprog_keyed_test", "k1", ["keyed_square"], build, opt="-O1")
        assert float(fns["keyed_square"](3.0)) == 9.0
    assert len(calls) == 1
    compile_keyed("hyprog_keyed_test", "k2", ["keyed_square"], build, opt="-O1")
    assert len(calls) == 2  # another key: built and compiled again


def test_a_models_libraries_compile_side_by_side_and_only_the_missing_one_is_built(
        tmp_path, monkeypatch):
    """``compile_keyed_all``: two missing libraries' compilers overlap (a wrapper compiler
    that logs its start and end around 1 s of sleep: both start before either ends); with one
    library in the cache, only the other is built and compiled."""
    import shutil

    import casadi as ca

    from engine_model.solver.codegen import KeyedLibrary, compile_keyed_all, compiler

    log = tmp_path / "calls.log"
    wrapper = tmp_path / "slow-cc"
    wrapper.write_text(f"#!/bin/sh\necho start >> {log}\nsleep 1\n"
                       f"{shutil.which(compiler())} \"$@\"\nrc=$?\necho end >> {log}\n"
                       "exit $rc\n")
    wrapper.chmod(0o755)
    monkeypatch.setenv("HYPROG_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", str(wrapper))
    built = []

    def job(name, power, key="k1"):
        def build():
            built.append(name)
            x = ca.SX.sym("x")
            return [ca.Function(name, [x], [x ** power])]
        return KeyedLibrary(f"hyprog_{name}", key, (name,), build, opt="-O1")

    square, cube = compile_keyed_all([job("pair_square", 2), job("pair_cube", 3)])
    assert float(square["pair_square"](3.0)) == 9.0 and float(cube["pair_cube"](2.0)) == 8.0
    assert log.read_text().split() == ["start", "start", "end", "end"]
    assert built == ["pair_square", "pair_cube"]
    log.write_text("")
    square, cube = compile_keyed_all([job("pair_square", 2), job("pair_cube", 3, key="k2")])
    assert float(cube["pair_cube"](2.0)) == 8.0
    assert built == ["pair_square", "pair_cube", "pair_cube"]
    assert log.read_text().split() == ["start", "end"]


def _compile_square(cache: str, cc: str) -> float:
    """In a fresh process: the library of ``x * x`` from ``cache`` with the compiler ``cc``."""
    import os

    import casadi as ca

    os.environ["HYPROG_CACHE"], os.environ["CC"] = cache, cc
    from engine_model.solver.codegen import compile_functions

    x = ca.SX.sym("x")
    fns = compile_functions("hyprog_locked_test", [ca.Function("locked_square", [x], [x * x])],
                            opt="-O1")
    return float(fns["locked_square"](3.0))


def test_processes_that_need_one_library_at_once_compile_it_once(tmp_path):
    """Two processes missing the same library in the cache: one compiles (here a compiler
    that takes 2 s), the other waits on the lock and loads it; before, both compiled."""
    import multiprocessing
    import shutil

    from engine_model.solver.codegen import compiler

    log = tmp_path / "calls.log"
    wrapper = tmp_path / "slow-cc"
    wrapper.write_text(f"#!/bin/sh\necho run >> {log}\nsleep 2\nexec {shutil.which(compiler())}"
                       ' "$@"\n')
    wrapper.chmod(0o755)
    cache = tmp_path / "cache"
    with multiprocessing.get_context("spawn").Pool(2) as pool:
        got = pool.starmap(_compile_square, [(str(cache), str(wrapper))] * 2)
    assert got == [9.0, 9.0]
    assert log.read_text().split() == ["run"]
    assert len(list(cache.glob("hyprog_locked_test_*.so"))) == 1


def _load_or_build_tiny_table(path: str, log: str) -> float:
    """In a fresh process: a one-node starting-guess table from ``path``, built (slowly,
    logging it) when missing."""
    import time
    from pathlib import Path

    import numpy as np

    from engine_model.solver.guess_table import GuessTable

    def build():
        with open(log, "a") as fh:
            fh.write("build\n")
        time.sleep(2.0)
        return GuessTable(np.full((1, 1, 1, 1, 2), 3.0), np.zeros((1, 1, 1, 1, 2, 1)), 1000.0,
                          abs, abs)

    tab = GuessTable.load_or_build(Path(path), build, 1000.0, abs, abs)
    return float(tab.table.sum())


def test_processes_that_need_the_guess_table_at_once_build_it_once(tmp_path):
    """Two processes missing the starting-guess table: one builds it (here in 2 s), the other
    waits on the lock and loads it (about 30 s of solves for the real table; before, both
    built it)."""
    import multiprocessing

    log, path = tmp_path / "calls.log", tmp_path / "table_test.npz"
    with multiprocessing.get_context("spawn").Pool(2) as pool:
        got = pool.starmap(_load_or_build_tiny_table, [(str(path), str(log))] * 2)
    assert got == [6.0, 6.0]
    assert log.read_text().split() == ["build"]
    assert path.is_file()
