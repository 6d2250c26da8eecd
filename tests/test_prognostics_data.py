"""Prognostics data handling: input sets, scaling on training units only, validation by whole
flights, and windows that are strided views and never cross a unit or a split.

Synthetic feature tables (tests/conftest.py ``synthetic_features``); no engine model.
"""

import numpy as np
import pandas as pd
import pytest
import torch

from engine_model.channels import THETA_NAMES, W_NAMES, XS_NAMES, XV_NAMES
from engine_model.validation import InputError
from prognostics.features import check_table, resolve_inputs, unobservable_columns
from prognostics.scaling import MinMaxScaler
from prognostics.splits import (
    CONFORMAL,
    TEST,
    TRAIN,
    UNUSED,
    VALIDATION,
    assign_roles,
    development_and_test_units,
    segments,
)
from prognostics.train_config import TrainConfig
from prognostics.training import prepare
from prognostics.windows import make_windows

pytestmark = pytest.mark.usefixtures("torch_one_thread")

# ---------------------------------------------------------------------------------------------
# input sets
# ---------------------------------------------------------------------------------------------


def test_paper_input_sets_on_a_full_table(make_features):
    df, _ = make_features(units=(1,), test_units=())
    cols = list(df.columns)
    dd = resolve_inputs("data-driven", cols)
    hy = resolve_inputs("hybrid", cols)
    assert dd == [*W_NAMES, *XS_NAMES] and len(dd) == 20  # the paper's [w, x_s]
    assert len(hy) == 50  # [w, x_s, x̂_s, x̂_v, θ̂] with ds02's three θ̂
    assert hy[:20] == dd
    assert hy[-3:] == ["HPT_eff_mod_hat", "LPT_eff_mod_hat", "LPT_flow_mod_hat"]
    assert not any(c.endswith("_std") for c in hy)  # the θ̂ std is not an input
    assert len(resolve_inputs("denoised", cols)) == 36
    assert len(resolve_inputs("virtual", cols)) == 47
    tt = resolve_inputs("truth-theta", cols)
    assert len(tt) == 50 and tt[-3:] == ["HPT_eff_mod", "LPT_eff_mod", "LPT_flow_mod"]
    # true theta of the estimated parameters only, not the 7 constant others
    assert not set(THETA_NAMES[:6]) & set(tt)


@pytest.mark.parametrize("spec, message", [
    ("", "inputs: empty specification"),
    ("hybrid++health", "inputs 'hybrid++health': empty term between '+'"),
    ("nonsense", "t.parquet: no input column(s) nonsense (an input term is a set or group"),
])
def test_an_input_specification_that_names_nothing(make_features, spec, message):
    df, _ = make_features(units=(1,), test_units=())
    with pytest.raises(InputError) as info:
        resolve_inputs(spec, list(df.columns), source="t.parquet")
    assert str(info.value).startswith(message), str(info.value)


def test_set_plus_columns_and_explicit_lists(make_features):
    df, _ = make_features(units=(1,), test_units=())
    df["phi"] = 1.0
    cols = list(df.columns)
    spec = resolve_inputs("hybrid+Ps30,phi", cols)
    assert len(spec) == 51 and spec[-1] == "phi"  # Ps30 is already in x_s: not twice
    assert resolve_inputs("alt,Mach,TRA,T2,T24", cols) == ["alt", "Mach", "TRA", "T2", "T24"]
    assert resolve_inputs("w+xv", cols) == [*W_NAMES, *XV_NAMES]


def test_a_missing_explicit_column_is_named(make_features):
    df, _ = make_features(units=(1,), test_units=())
    with pytest.raises(InputError, match=r"feat\.parquet: no input column\(s\) htBleed"):
        resolve_inputs("hybrid+Ps30,htBleed", list(df.columns), "feat.parquet")


def test_a_set_whose_group_is_absent_is_an_error_not_a_smaller_set(make_features):
    df, _ = make_features(units=(1,), test_units=())
    raw = [c for c in df.columns if not c.endswith("_hat") and not c.endswith("_std")]
    assert len(resolve_inputs("data-driven", raw)) == 20
    with pytest.raises(InputError, match="xs_hat.*hyprog calibrate"):
        resolve_inputs("hybrid", raw)
    with pytest.raises(InputError, match="RUL cannot be an input"):
        resolve_inputs("w+RUL", list(df.columns))
    with pytest.raises(InputError, match="unknown|no input column"):
        resolve_inputs("hybird", list(df.columns))


def test_a_parameter_unobservable_in_every_unit_leaves_the_health_groups(make_features):
    """``calibrate --params all`` writes NaN for a parameter it cannot observe: a column NaN
    in every row is left out of theta_hat (and theta); one NaN in some rows stays an error."""
    df, _ = make_features(units=(1, 2), test_units=())
    hats = [c for c in df.columns if c.endswith("_hat") and c[:-4] in THETA_NAMES]
    gone = df.assign(**{hats[0]: np.nan})
    assert unobservable_columns(gone) == [hats[0]]
    cols = resolve_inputs("hybrid", list(gone.columns), unobservable=unobservable_columns(gone))
    assert hats[0] not in cols and hats[1] in cols
    truth = resolve_inputs("truth-theta", list(gone.columns),
                           unobservable=unobservable_columns(gone))
    assert hats[0][:-4] not in truth and hats[1][:-4] in truth
    some = df.copy()
    some.loc[some.index[some.unit == 2][0], hats[0]] = np.nan
    assert unobservable_columns(some) == []
    with pytest.raises(InputError, match=f"unit 2, cycle 1, column {hats[0]}"):
        check_table(some, resolve_inputs("hybrid", list(some.columns)))


def test_check_table_names_unit_cycle_and_column_of_a_nan(make_features):
    df, _ = make_features(units=(1, 2), test_units=())
    df.loc[df.index[(df.unit == 2) & (df.cycle == 3)][1], "T24"] = np.nan
    with pytest.raises(InputError, match="unit 2, cycle 3, column T24"):
        check_table(df, resolve_inputs("data-driven", list(df.columns)))


# ---------------------------------------------------------------------------------------------
# scaling
# ---------------------------------------------------------------------------------------------


def test_minmax_scaler_maps_training_range_to_minus_one_one():
    x = np.array([[0.0, 5.0, 2.0], [10.0, 5.0, 4.0], [5.0, 5.0, 3.0]])
    s = MinMaxScaler.fit(x, ["a", "b", "c"])
    z = s.transform(x)
    assert z.dtype == np.float32 and z.flags.c_contiguous
    np.testing.assert_allclose(z[:, 0], [-1, 1, 0])
    np.testing.assert_allclose(z[:, 1], 0.0)  # a constant column maps to 0, no division by 0
    np.testing.assert_allclose(s.transform(np.array([[20.0, 7.0, 1.0]])), [[3.0, 0.0, -2.0]])
    assert MinMaxScaler.from_dict(s.to_dict()).to_dict() == s.to_dict()
    # the column-by-column form (what training uses: no float64 copy of the table) is the same
    df = pd.DataFrame(x, columns=["a", "b", "c"])
    rows = np.array([True, False, True])
    f = MinMaxScaler.fit_frame(df, ["a", "b", "c"], rows)
    assert f.to_dict() == MinMaxScaler.fit(x[rows], ["a", "b", "c"]).to_dict()
    np.testing.assert_array_equal(f.transform_frame(df), f.transform(x))
    assert f.transform_frame(df).flags.c_contiguous


def test_scaler_sees_the_training_rows_only(make_features):
    """Spikes planted in a validation flight, a conformal unit and a test unit do not move the
    scaler; it equals the min / max of the training rows exactly."""
    df, meta = make_features()
    cfg = TrainConfig(model="cnn", inputs="data-driven", window=5, seed=3,
                      conformal_units=(4,)).resolved()
    dev = meta["dev_units"]
    frame = df[df.unit.isin(dev)].reset_index(drop=True)
    roles = assign_roles(frame.unit.to_numpy(), frame.cycle.to_numpy(), dev, seed=cfg.seed,
                         conformal_units=(4,), validation="units")  # the default (issue 30)
    val_row = frame.index[roles == VALIDATION][0]
    val_key = frame.loc[val_row, ["unit", "cycle", "t"]]
    at = (df.unit == val_key.unit) & (df.cycle == val_key.cycle) & (df.t == val_key.t)
    df.loc[at, "T24"] = 1e6
    df.loc[df.unit == 4, "T30"] = -1e6  # conformal unit
    df.loc[df.unit == 5, "Nf"] = 1e9  # test unit
    prep = prepare(df, meta, cfg)
    np.testing.assert_array_equal(prep.roles, roles)  # the same draw as above
    raw = prep.frame.merge(df, on=["unit", "cycle", "t"], how="left")[prep.columns].to_numpy()
    train = raw[prep.roles == TRAIN]
    np.testing.assert_array_equal(prep.scaler.minimum, train.min(axis=0))
    np.testing.assert_array_equal(prep.scaler.maximum, train.max(axis=0))
    j = {c: prep.columns.index(c) for c in ("T24", "T30", "Nf")}
    assert prep.scaler.maximum[j["T24"]] < 1e3
    assert prep.scaler.minimum[j["T30"]] > -1e3
    assert prep.scaler.maximum[j["Nf"]] < 1e3
    assert 5 not in prep.frame.unit.to_numpy()  # test units never reach training


# ---------------------------------------------------------------------------------------------
# splits
# ---------------------------------------------------------------------------------------------


def test_validation_is_whole_flights_about_ten_percent_per_unit(make_features):
    df, meta = make_features(units=(1, 2, 3, 4), test_units=(4,), cycles=(30, 40))
    unit, cycle = df.unit.to_numpy(), df.cycle.to_numpy()
    roles = assign_roles(unit, cycle, [1, 2, 3], [4], seed=11)
    assert set(np.unique(roles[unit == 4])) == {TEST}
    per_flight = pd.DataFrame({"unit": unit, "cycle": cycle, "role": roles}) \
        .groupby(["unit", "cycle"])["role"].nunique()
    assert per_flight.max() == 1  # no flight on both sides
    for u in (1, 2, 3):
        n_cycles = len(np.unique(cycle[unit == u]))
        n_val = len(np.unique(cycle[(unit == u) & (roles == VALIDATION)]))
        assert n_val == max(1, round(0.1 * n_cycles))
    again = assign_roles(unit, cycle, [1, 2, 3], [4], seed=11)
    other = assign_roles(unit, cycle, [1, 2, 3], [4], seed=12)
    np.testing.assert_array_equal(roles, again)  # the seed fixes the draw
    assert not np.array_equal(roles, other)
    # the draw depends on the set of units, not on the order they were listed in
    np.testing.assert_array_equal(roles, assign_roles(unit, cycle, [3, 1, 2], [4], seed=11))
    by_unit = assign_roles(unit, cycle, [1, 2, 3], [4], seed=5, validation="units",
                           val_fraction=0.34)
    np.testing.assert_array_equal(by_unit, assign_roles(
        unit, cycle, [2, 3, 1], [4], seed=5, validation="units", val_fraction=0.34))


def test_validation_units_conformal_units_and_refusals(make_features):
    df, _ = make_features()
    unit, cycle = df.unit.to_numpy(), df.cycle.to_numpy()
    r = assign_roles(unit, cycle, [1, 2, 3, 4], [5], validation="units", val_units=[2],
                     conformal_units=[3])
    assert set(np.unique(r[unit == 2])) == {VALIDATION}
    assert set(np.unique(r[unit == 3])) == {CONFORMAL}
    assert set(np.unique(r[unit == 6])) == {UNUSED}
    assert set(np.unique(r[np.isin(unit, [1, 4])])) == {TRAIN}
    with pytest.raises(InputError, match="unit.* 5 are both development and test"):
        assign_roles(unit, cycle, [1, 5], [5])
    with pytest.raises(InputError, match="conformal but not development"):
        assign_roles(unit, cycle, [1, 2], [5], conformal_units=[5])
    with pytest.raises(InputError, match="validation unit.* 3 are not training units"):
        assign_roles(unit, cycle, [1, 2, 3], [], validation="units", val_units=[3],
                     conformal_units=[3])
    with pytest.raises(InputError, match="unit.* 9 not in the table"):
        development_and_test_units([1, 2], None, units=[1, 9])


# ---------------------------------------------------------------------------------------------
# windows
# ---------------------------------------------------------------------------------------------


def _window_rows(w):
    """(n_windows, L) base-row indices of every window."""
    return w.starts.numpy()[:, None] + np.arange(w.length)[None, :]


def test_windows_never_cross_units_or_splits_and_are_views(make_features):
    df, meta = make_features(samples=(20, 30))  # every segment longer than the window
    cfg = TrainConfig(model="cnn", inputs="hybrid", window=12, seed=1, conformal_units=(4,))
    prep = prepare(df, meta, cfg)
    unit = prep.frame.unit.to_numpy()
    x = prep.scaler.transform(
        prep.frame.merge(df, on=["unit", "cycle", "t"])[prep.columns].to_numpy())
    seen = 0
    for role, w in prep.windows.items():
        assert role in (TRAIN, VALIDATION, CONFORMAL)
        rows = _window_rows(w)
        # all rows of a window: one unit, the window's role, and consecutive in the table
        assert np.all(unit[rows] == unit[rows[:, :1]])
        assert np.all(prep.roles[rows] == role)
        assert np.array_equal(rows[:, -1], w.rows)  # target at the window's last row
        np.testing.assert_array_equal(w.target.numpy(),
                                      prep.frame.RUL.to_numpy(np.float32)[w.rows])
        # a strided view of one base: no copy per window
        v = w.view()
        assert v.shape == (len(w.base) - 12 + 1, w.n_features, 12)
        assert v.untyped_storage().data_ptr() == w.base.untyped_storage().data_ptr()
        assert v.stride() == (w.n_features, 1, w.n_features)
        np.testing.assert_array_equal(w.batch(torch.tensor([0])).numpy()[0],
                                      x[rows[0]].T)
        seen += len(w)
    # train, validation and conformal windows all view the same scaled rows
    bases = [w.base.numpy() for w in prep.windows.values()]
    assert all(np.shares_memory(bases[0], b) for b in bases[1:])
    # every segment of n >= L rows gives n - L + 1 windows
    a, b = segments(unit, prep.roles)
    keep = prep.roles[a] != UNUSED
    assert seen == int(np.sum(b[keep] - a[keep] - 12 + 1))


def test_make_windows_shares_memory_with_its_input_and_handles_stride():
    x = np.arange(40, dtype=np.float32).reshape(20, 2)
    w = make_windows(x, np.array([0, 8]), np.array([8, 20]), length=4, stride=2,
                     target=np.arange(20.0))
    assert np.shares_memory(w.base.numpy(), x)
    assert w.starts.tolist() == [0, 2, 4, 8, 10, 12, 14, 16]
    assert w.rows.tolist() == [3, 5, 7, 11, 13, 15, 17, 19]
    assert w.target.tolist() == [3, 5, 7, 11, 13, 15, 17, 19]
    batch = w.batch(torch.tensor([3]))
    assert batch.shape == (1, 2, 4)
    np.testing.assert_array_equal(batch[0].numpy(), x[8:12].T)
    assert batch.transpose(1, 2).is_contiguous()  # rows kept whole: channels-last conv input
    fnn = make_windows(x, np.array([0]), np.array([20]), length=1)
    assert len(fnn) == 20 and fnn.batch(torch.tensor([5])).tolist() == [x[5].tolist()]


def test_a_segment_shorter_than_the_window_is_left_padded_with_its_first_row():
    x = np.arange(14, dtype=np.float32).reshape(7, 2)
    # segments: rows 0-1 (short), rows 2-6 (5 rows, window 4 -> 2 windows)
    w = make_windows(x, np.array([0, 2]), np.array([2, 7]), length=4, target=np.arange(7.0))
    assert len(w) == 3
    assert w.rows.tolist() == [1, 5, 6]  # the short segment's one window ends at its last row
    first = w.batch(torch.tensor([0]))[0].numpy().T
    np.testing.assert_array_equal(first, x[[0, 0, 0, 1]])
    np.testing.assert_array_equal(w.batch(torch.tensor([1]))[0].numpy().T, x[2:6])
    assert w.target.tolist() == [1.0, 5.0, 6.0]


def test_window_arguments_are_checked():
    x = np.zeros((5, 1), np.float32)
    with pytest.raises(InputError, match="length and stride"):
        make_windows(x, np.array([0]), np.array([5]), length=0)
    with pytest.raises(InputError, match="segment"):
        make_windows(x, np.array([3]), np.array([9]), length=2)
