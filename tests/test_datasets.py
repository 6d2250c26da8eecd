"""Fleet data sets on disk: hyprog parquet and the N-CMAPSS h5 layout (engine_model.datasets).

Every table here is a small synthetic fleet made with numpy (3 units, a few cycles, a few
samples per cycle), so the module runs in well under a second.
"""

import json
import os

import h5py
import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from pandas.testing import assert_frame_equal

from engine_model import datasets
from engine_model.channels import (
    NCMAPSS_XS,
    NCMAPSS_XV,
    THETA_NAMES,
    W_NAMES,
    XS_NAMES,
    XV_NAMES,
)
from engine_model.datasets import (
    ncmapss_h5,
    parquet,
    read_dataset,
    read_metadata,
    read_ncmapss_h5,
    read_parquet,
    summarize,
    write_dataset,
    write_ncmapss_h5,
    write_parquet,
)
from engine_model.validation import InputError

RATE_HZ = 2.0
UNITS = (2, 5, 11)
DEV, TEST = [2, 5], [11]
META = {
    "preset": "ds02-mini", "seed": 7, "sample_rate_hz": RATE_HZ,
    "effects": [{"name": "customer_bleed", "params": {"fraction": 0.02}}],
    "hyprog_version": "0.1.0", "dev_units": DEV, "test_units": TEST,
    "note": "an unknown key is kept",
}
INT_COLUMNS = ("unit", "cycle", "Fc", "hs", "RUL")
REAL_LAYOUT = {
    f"{g}_{s}" for g in ("W", "X_s", "X_v", "T", "Y", "A") for s in ("dev", "test")
} | {"W_var", "X_s_var", "X_v_var", "T_var", "A_var"}


def make_fleet(units=UNITS, rate_hz=RATE_HZ, seed=0):
    """A fleet table in the simulator's schema: t = sample index / rate within each cycle."""
    rng = np.random.default_rng(seed)
    cols = {name: [] for name in ("unit", "cycle", "t", "Fc", "hs", "RUL")}
    for u in units:
        n_cycles = 3 + u % 3
        onset = 2
        for c in range(1, n_cycles + 1):
            n = 3 + (u + c) % 4
            cols["unit"].append(np.full(n, u))
            cols["cycle"].append(np.full(n, c))
            cols["t"].append(np.arange(n) / rate_hz)
            cols["Fc"].append(np.full(n, 1 + u % 3))
            cols["hs"].append(np.full(n, int(c < onset)))
            cols["RUL"].append(np.full(n, n_cycles - c))
    df = pd.DataFrame({k: np.concatenate(v) for k, v in cols.items()})
    for k in INT_COLUMNS:
        df[k] = df[k].astype(np.int64)
    n = len(df)
    w = {"alt": rng.uniform(0, 35000, n), "Mach": rng.uniform(0, 0.8, n),
         "TRA": rng.uniform(20, 100, n), "T2": rng.uniform(420, 540, n)}
    signals = {name: rng.normal(100.0, 10.0, n) for name in (*XS_NAMES, *XV_NAMES, "phi")}
    theta = {name: rng.uniform(-0.05, 0.0, n) for name in THETA_NAMES}
    return pd.concat([df, pd.DataFrame({**w, **signals, **theta})], axis=1)


def canonical(df):
    return df[datasets.canonical_columns(df.columns)]


def siblings(path):
    """Everything in the parent directory of ``path`` other than ``path`` itself."""
    return sorted(p.name for p in path.parent.iterdir() if p != path)


def tree_bytes(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


@pytest.fixture(scope="module")
def fleet():
    return make_fleet()


# ---------------------------------------------------------------------------------------------
# parquet
# ---------------------------------------------------------------------------------------------

def test_parquet_round_trip_values_dtypes_order_and_metadata(tmp_path, fleet):
    shuffled = fleet.sample(frac=1.0, random_state=3).reset_index(drop=True)
    path = write_parquet(shuffled, tmp_path / "fleet.parquet", META)
    df, meta = read_parquet(path)
    assert_frame_equal(df, fleet, check_exact=True)
    for k in INT_COLUMNS:
        assert df[k].dtype == np.int64, k
    assert df["t"].dtype == np.float64
    assert meta == META
    assert read_metadata(path) == META


def test_parquet_is_partitioned_by_unit_with_metadata_in_every_part(tmp_path, fleet):
    path = write_parquet(fleet, tmp_path / "fleet", META)
    assert sorted(p.name for p in path.iterdir()) == ["unit=11", "unit=2", "unit=5"]
    for u in UNITS:
        part = path / f"unit={u}" / "part-0.parquet"
        schema = pq.read_schema(part)
        assert "unit" not in schema.names  # the directory name holds it
        assert json.loads(schema.metadata[b"hyprog"]) == META
        assert pq.read_metadata(part).num_rows == int((fleet["unit"] == u).sum())
    assert siblings(path) == []  # no temporary left behind


def test_parquet_bytes_are_deterministic(tmp_path, fleet):
    a = tree_bytes(write_parquet(fleet, tmp_path / "a", META))
    b = tree_bytes(write_parquet(fleet.iloc[::-1], tmp_path / "b", dict(reversed(META.items()))))
    assert sorted(a) == ["unit=11/part-0.parquet", "unit=2/part-0.parquet",
                         "unit=5/part-0.parquet"]
    assert a == b


def test_parquet_hyprog_version_filled_in_when_absent(tmp_path, fleet):
    meta = {k: v for k, v in META.items() if k != "hyprog_version"}
    _, back = read_parquet(write_parquet(fleet, tmp_path / "f", meta))
    assert back == {**meta, "hyprog_version": datasets.hyprog_version()}


def _fail_on_second_part(monkeypatch):
    real = parquet._write_part
    calls = []

    def flaky(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("disk full")
        real(*args, **kwargs)

    monkeypatch.setattr(parquet, "_write_part", flaky)
    return calls


def test_failed_parquet_write_leaves_no_target_and_no_temporary(tmp_path, fleet, monkeypatch):
    calls = _fail_on_second_part(monkeypatch)
    target = tmp_path / "fleet.parquet"
    with pytest.raises(RuntimeError, match="disk full"):
        write_parquet(fleet, target, META)
    assert len(calls) == 2  # it failed mid-write, after one unit was on disk
    assert list(tmp_path.iterdir()) == []


def test_failed_parquet_write_leaves_an_existing_target_untouched(tmp_path, fleet, monkeypatch):
    target = write_parquet(fleet.iloc[:40], tmp_path / "fleet.parquet", {"seed": 1})
    before = tree_bytes(target)
    _fail_on_second_part(monkeypatch)
    with pytest.raises(RuntimeError, match="disk full"):
        write_parquet(fleet, target, META)
    assert tree_bytes(target) == before
    assert siblings(target) == []


def test_parquet_overwrite_replaces_the_whole_directory(tmp_path, fleet):
    target = write_parquet(fleet, tmp_path / "fleet", META)
    (target / "stale.txt").write_text("from an older run")
    # a file hyprog did not write is never deleted without overwrite (the ownership rule)
    with pytest.raises(InputError, match="stale.txt"):
        write_parquet(fleet[fleet["unit"] == 5], target, {"seed": 2})
    assert (target / "stale.txt").read_text() == "from an older run"
    write_parquet(fleet[fleet["unit"] == 5], target, {"seed": 2}, overwrite=True)
    assert sorted(p.name for p in target.iterdir()) == ["unit=5"]
    assert read_metadata(target)["seed"] == 2
    assert siblings(target) == []


def test_parquet_units_and_columns_selection(tmp_path, fleet):
    path = write_parquet(fleet, tmp_path / "fleet", META)
    df, _ = read_parquet(path, units=[11, 2], columns=["T48", "HPT_eff_mod"])
    assert list(df.columns) == ["unit", "cycle", "t", "T48", "HPT_eff_mod"]
    want = fleet[fleet["unit"].isin([2, 11])][list(df.columns)].reset_index(drop=True)
    assert_frame_equal(df, want, check_exact=True)
    with pytest.raises(InputError, match=r"unit\(s\) 3 not in the file"):
        read_parquet(path, units=[3])
    with pytest.raises(InputError, match="no column.*Fn"):
        read_parquet(path, columns=["Fn"])


def test_parquet_reads_a_single_file(tmp_path, fleet):
    path = write_parquet(fleet, tmp_path / "fleet", META)
    part, meta = read_parquet(path / "unit=5" / "part-0.parquet")  # unit from the directory
    assert meta == META
    assert_frame_equal(part, fleet[fleet["unit"] == 5].reset_index(drop=True), check_exact=True)
    flat = tmp_path / "flat.parquet"
    pq.write_table(pq.read_table(path / "unit=5" / "part-0.parquet").append_column(
        "unit", [np.full(len(part), 5)]), flat)
    df, _ = read_parquet(flat)
    assert df["unit"].dtype == np.int64
    assert_frame_equal(df, part, check_exact=True)


def test_missing_sensor_channels_are_allowed(tmp_path, fleet):
    drop = ["Wf", "T40", "P30", "SmHPC", *THETA_NAMES]
    part = fleet.drop(columns=drop)
    df, _ = read_parquet(write_parquet(part, tmp_path / "p", META))
    assert_frame_equal(df, part, check_exact=True)
    h5 = write_ncmapss_h5(part, tmp_path / "p.h5", META)
    with h5py.File(h5) as f:
        assert "T_dev" not in f and "T_var" not in f
        assert [n.decode() for n in f["X_s_var"][()]] == [n for n in NCMAPSS_XS if n != "Wf"]
        assert f["X_v_dev"].shape[1] == 11
    back, _ = read_ncmapss_h5(h5)
    assert_frame_equal(back, canonical(part), check_exact=True)


# ---------------------------------------------------------------------------------------------
# errors a user can act on
# ---------------------------------------------------------------------------------------------

def test_errors_name_the_file_and_the_column(tmp_path, fleet):
    missing = tmp_path / "nope.parquet"
    with pytest.raises(InputError, match="nope.parquet: no such file"):
        read_dataset(missing)
    text = tmp_path / "notes.parquet"
    text.write_text("not parquet")
    with pytest.raises(InputError, match="notes.parquet: not a parquet"):
        read_parquet(text)
    fake_h5 = tmp_path / "notes.h5"
    fake_h5.write_text("not hdf5")
    with pytest.raises(InputError, match="notes.h5: not an HDF5"):
        read_dataset(fake_h5)
    with pytest.raises(InputError, match="out.parquet.*missing column.*Mach"):
        write_parquet(fleet.drop(columns="Mach"), tmp_path / "out.parquet", META)
    nan_cycle = fleet.assign(cycle=fleet["cycle"].astype(float))
    nan_cycle.loc[7, "cycle"] = np.nan
    with pytest.raises(InputError, match="out.h5: column cycle is NaN.* row 7"):
        write_ncmapss_h5(nan_cycle, tmp_path / "out.h5", META)
    no_t2 = tmp_path / "no_t2.parquet"
    pq.write_table(pq.read_table(write_parquet(fleet, tmp_path / "ok", META)).drop(["T2"]),
                   no_t2)
    with pytest.raises(InputError, match="no_t2.parquet: missing column.*T2"):
        read_parquet(no_t2)
    assert not (tmp_path / "out.parquet").exists() and not (tmp_path / "out.h5").exists()


# ---------------------------------------------------------------------------------------------
# N-CMAPSS h5
# ---------------------------------------------------------------------------------------------

def test_h5_round_trip(tmp_path, fleet):
    path = write_ncmapss_h5(fleet.iloc[::-1], tmp_path / "fleet.h5", META)
    df, meta = read_ncmapss_h5(path)
    assert_frame_equal(df, canonical(fleet), check_exact=True)
    assert meta == {**META, "source_format": "ncmapss-h5"}
    dev, _ = read_ncmapss_h5(path, split="dev")
    assert sorted(dev["unit"].unique()) == DEV
    assert siblings(path) == []


def test_h5_file_has_the_published_layout(tmp_path, fleet):
    path = write_ncmapss_h5(fleet, tmp_path / "fleet.h5", META)
    n = {s: int(fleet["unit"].isin(u).sum()) for s, u in (("dev", DEV), ("test", TEST))}
    widths = {"W": 4, "X_s": 14, "X_v": 14, "T": 10, "Y": 1, "A": 4}
    with h5py.File(path) as f:
        assert set(f.keys()) == REAL_LAYOUT
        for name in REAL_LAYOUT - {k for k in REAL_LAYOUT if k.endswith("_var")}:
            group, split = name.rsplit("_", 1)
            assert f[name].shape == (n[split], widths[group]), name
        for var, names in (("W_var", W_NAMES), ("X_s_var", NCMAPSS_XS),
                           ("X_v_var", NCMAPSS_XV), ("T_var", THETA_NAMES),
                           ("A_var", ("unit", "cycle", "Fc", "hs"))):
            assert f[var].dtype.kind == "S", var
            assert tuple(v.decode() for v in f[var][()]) == names
        assert f["W_dev"].dtype == np.float64 and f["X_s_test"].dtype == np.float64
        x_s = f["X_s_dev"][()]
        y = f["Y_test"][()]
        stored = json.loads(f.attrs["hyprog"])
    dev = fleet[fleet["unit"].isin(DEV)]
    np.testing.assert_array_equal(x_s, dev[list(NCMAPSS_XS)].to_numpy())
    np.testing.assert_array_equal(y[:, 0], fleet.loc[fleet["unit"] == 11, "RUL"].to_numpy())
    assert stored["dev_units"] == DEV and stored["test_units"] == TEST


def write_raw_ncmapss(path, table, dev, test, perm_seed=1, drop=()):
    """An h5 file as the published ones are made: float64 everywhere (A and Y too), names as
    byte strings, columns in a permuted order, no hyprog attribute."""
    rng = np.random.default_rng(perm_seed)
    groups = {"W": W_NAMES, "X_s": NCMAPSS_XS, "X_v": NCMAPSS_XV, "T": THETA_NAMES,
              "A": ("unit", "cycle", "Fc", "hs")}
    order = {g: [names[i] for i in rng.permutation(len(names))] for g, names in groups.items()}
    with h5py.File(path, "w") as f:
        for g, names in order.items():
            f.create_dataset(f"{g}_var", data=np.array(names, dtype="S"))
        for split, units in (("dev", dev), ("test", test)):
            rows = table[table["unit"].isin(units)]
            for g, names in order.items():
                if f"{g}_{split}" not in drop:
                    f.create_dataset(f"{g}_{split}", data=rows[names].to_numpy(np.float64))
            if f"Y_{split}" not in drop:
                f.create_dataset(f"Y_{split}", data=rows[["RUL"]].to_numpy(np.float64))


def test_h5_reads_the_published_layout_by_name(tmp_path, fleet):
    path = tmp_path / "N-CMAPSS_DS02-006.h5"
    write_raw_ncmapss(path, fleet, DEV, TEST)
    with h5py.File(path) as f:
        assert [v.decode() for v in f["X_s_var"][()]] != list(NCMAPSS_XS)  # really permuted
    df, meta = read_ncmapss_h5(path)
    one_hz = canonical(fleet).assign(t=fleet["t"] * RATE_HZ)  # no rate in the file: 1 Hz
    assert_frame_equal(df, one_hz, check_exact=True)
    for k in INT_COLUMNS:
        assert df[k].dtype == np.int64, k
    assert meta == {"dev_units": DEV, "test_units": TEST, "source_format": "ncmapss-h5",
                    "sample_rate_hz": 1.0}


def test_h5_units_filter_reads_only_those_units(tmp_path, fleet):
    path = tmp_path / "raw.h5"
    write_raw_ncmapss(path, fleet, DEV, TEST)
    df, meta = read_ncmapss_h5(path, units=[5, 11])
    assert sorted(df["unit"].unique()) == [5, 11]
    want = canonical(fleet[fleet["unit"].isin([5, 11])]).reset_index(drop=True)
    assert_frame_equal(df, want.assign(t=want["t"] * RATE_HZ), check_exact=True)
    assert meta["dev_units"] == DEV and meta["test_units"] == TEST  # the file, not the selection
    test_only, _ = read_ncmapss_h5(path, split="test", columns=["T48"])
    assert list(test_only.columns) == ["unit", "cycle", "t", "T48"]
    assert sorted(test_only["unit"].unique()) == TEST
    with pytest.raises(InputError, match=r"unit\(s\) 4 not in the file"):
        read_ncmapss_h5(path, units=[4])


def test_h5_structural_errors_name_the_file_and_the_dataset(tmp_path, fleet):
    no_a = tmp_path / "no_a.h5"
    write_raw_ncmapss(no_a, fleet, DEV, TEST, drop=("A_dev",))
    with pytest.raises(InputError, match=r"no_a.h5: dataset A_dev is missing"):
        read_ncmapss_h5(no_a)
    test_only, _ = read_ncmapss_h5(no_a, split="test")  # the intact split still reads
    assert sorted(test_only["unit"].unique()) == TEST

    short = tmp_path / "short.h5"
    write_raw_ncmapss(short, fleet, DEV, TEST)
    with h5py.File(short, "a") as f:
        x = f["X_s_dev"][:-1]
        del f["X_s_dev"]
        f.create_dataset("X_s_dev", data=x)
    with pytest.raises(InputError, match=r"short.h5: row counts differ.*X_s_dev \d+"):
        read_ncmapss_h5(short)

    nan_unit = tmp_path / "nan_unit.h5"
    write_raw_ncmapss(nan_unit, fleet, DEV, TEST)
    with h5py.File(nan_unit, "a") as f:
        j = [v.decode() for v in f["A_var"][()]].index("unit")
        f["A_test"][3, j] = np.nan
    # index 3 is the fourth row: rows are counted from 1, as in every other message
    with pytest.raises(InputError, match=r"nan_unit.h5: A_test, column unit is NaN at row 4"):
        read_ncmapss_h5(nan_unit)

    no_var = tmp_path / "no_var.h5"
    write_raw_ncmapss(no_var, fleet, DEV, TEST)
    with h5py.File(no_var, "a") as f:
        del f["X_v_var"]
    with pytest.raises(InputError, match=r"no_var.h5: dataset X_v_var"):
        read_ncmapss_h5(no_var)


def test_h5_splits_and_atomicity(tmp_path, fleet, monkeypatch):
    all_dev = write_ncmapss_h5(fleet, tmp_path / "all_dev.h5",
                               {"seed": 1, "sample_rate_hz": RATE_HZ})
    with h5py.File(all_dev) as f:
        assert f["A_test"].shape == (0, 4) and f["W_dev"].shape == (len(fleet), 4)
    with pytest.raises(InputError, match=r"unit\(s\) 11 are in neither"):
        write_ncmapss_h5(fleet, tmp_path / "x.h5", {"dev_units": [2], "test_units": [5]})

    before = all_dev.read_bytes()
    real = ncmapss_h5._create

    def failing(f, name, *args):
        if name == "X_v_test":
            raise OSError("disk full")
        real(f, name, *args)

    monkeypatch.setattr(ncmapss_h5, "_create", failing)
    with pytest.raises(OSError, match="disk full"):
        write_ncmapss_h5(fleet, all_dev, META)
    with pytest.raises(OSError, match="disk full"):
        write_ncmapss_h5(fleet, tmp_path / "new.h5", META)
    assert all_dev.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["all_dev.h5"]


def test_h5_warns_about_what_it_cannot_store(tmp_path, fleet):
    odd = fleet.assign(Fn=1.0, t=fleet["t"] + 0.25)
    with pytest.warns(UserWarning) as record:
        write_ncmapss_h5(odd, tmp_path / "odd.h5", META)
    text = " ".join(str(r.message) for r in record)
    assert "Fn" in text and "column t" in text


# ---------------------------------------------------------------------------------------------
# dispatch and summary
# ---------------------------------------------------------------------------------------------

def test_read_and_write_dataset_dispatch(tmp_path, fleet):
    h5 = write_dataset(fleet, tmp_path / "fleet.hdf5", META)
    pqd = write_dataset(fleet, tmp_path / "fleet_dir", META, format="parquet")
    with open(h5, "rb") as fh:
        assert fh.read(8) == b"\x89HDF\r\n\x1a\n"
    assert (pqd / "unit=2" / "part-0.parquet").is_file()
    a, meta_a = read_dataset(h5, split="test")
    b, meta_b = read_dataset(pqd, split="test")
    assert_frame_equal(a, canonical(b), check_exact=True)
    assert sorted(b["unit"].unique()) == TEST
    assert meta_a["source_format"] == "ncmapss-h5" and "source_format" not in meta_b
    sniffed = tmp_path / "fleet.data"
    os.link(h5, sniffed)  # no telling suffix: the magic bytes decide
    assert_frame_equal(read_dataset(sniffed)[0], read_dataset(h5)[0])
    with pytest.raises(InputError, match="unknown format 'csv'"):
        write_dataset(fleet, tmp_path / "f.csv", META, format="csv")
    # a C-MAPSS text file given where a dataset is read: the error says how to import it
    text = tmp_path / "train_FD001.txt"
    text.write_text("1 1 -0.0007 -0.0004 100.0 518.67 641.82  \n")
    with pytest.raises(InputError, match="unknown format\\) \\(a C-MAPSS text file\\? import "
                       "it first: hyprog data import-cmapss\\)"):
        read_dataset(text)
    text.write_bytes(b"PAR2 not a dataset")
    with pytest.raises(InputError, match="unknown format\\)$"):
        read_dataset(text)


def test_summarize_counts_on_a_constructed_table():
    # unit 1: cycles 1-3, 2 samples each, abnormal from cycle 3, classes 1 and 2
    # unit 7: cycles 4-5, 3 samples each, healthy throughout, class 3
    df = pd.DataFrame({
        "unit": [1] * 6 + [7] * 6,
        "cycle": [1, 1, 2, 2, 3, 3] + [4, 4, 4, 5, 5, 5],
        "t": [0.0, 1.0] * 3 + [0.0, 1.0, 2.0] * 2,
        "Fc": [1, 1, 2, 2, 2, 2] + [3] * 6,
        "hs": [1, 1, 1, 1, 0, 0] + [1] * 6,
        "RUL": [2, 2, 1, 1, 0, 0] + [1, 1, 1, 0, 0, 0],
        "alt": 0.0, "Mach": 0.0, "TRA": 80.0, "T2": 518.67, "T48": 1800.0, "Fn": 1.0,
        "HPT_eff_mod": -0.01,
    })
    meta = {"dev_units": np.array([1]), "test_units": [7], "sample_rate_hz": 1,
            "effects": [{"name": "sensor_drift", "params": {"T48": 0.5}}], "preset": "tiny",
            "seed": np.int64(3)}
    s = summarize(df, meta)
    assert s["units"] == [
        {"unit": 1, "split": "dev", "cycles": 3, "rows": 6, "eol": 3, "t_s": 3, "Fc": [1, 2]},
        {"unit": 7, "split": "test", "cycles": 2, "rows": 6, "eol": 5, "t_s": None, "Fc": [3]},
    ]
    assert s["totals"] == {"units": 2, "rows": 12, "cycles": 5}
    assert s["sample_rate_hz"] == 1.0
    assert s["effects"] == [{"name": "sensor_drift", "params": {"T48": 0.5}}]
    assert s["columns"] == {
        "bookkeeping": ["unit", "cycle", "t", "Fc", "hs", "RUL"],
        "w": ["alt", "Mach", "TRA", "T2"], "x_s": ["T48"], "x_v": [],
        "theta": ["HPT_eff_mod"], "other": ["Fn"],
    }
    assert (s["dev_units"], s["test_units"], s["preset"], s["seed"]) == ([1], [7], "tiny", 3)
    assert json.loads(json.dumps(s)) == s  # plain python types only
    no_split = summarize(df.drop(columns=["hs", "Fc"]), {})
    assert [u["split"] for u in no_split["units"]] == ["dev", "dev"]
    assert [u["t_s"] for u in no_split["units"]] == [None, None]
    assert no_split["sample_rate_hz"] is None and no_split["effects"] == []


def test_parquet_unit_writer_streams_the_same_layout(tmp_path):
    df = make_fleet()
    meta = {"preset": "stream", "seed": 3}
    a = tmp_path / "whole"
    b = tmp_path / "streamed"
    datasets.write_parquet(df, a, meta)
    with datasets.parquet_unit_writer(b, meta) as write_unit:
        for _, part in df.groupby("unit", sort=True):
            write_unit(part)
    for f in sorted(a.rglob("*.parquet")):
        assert f.read_bytes() == (b / f.relative_to(a)).read_bytes()
    # an error mid-stream leaves nothing behind
    c = tmp_path / "broken"
    with (pytest.raises(RuntimeError, match="simulated crash"),
          datasets.parquet_unit_writer(c, meta) as write_unit):
        write_unit(df[df.unit == df.unit.iloc[0]])
        raise RuntimeError("simulated crash")
    assert not c.exists() and not list(tmp_path.glob(".broken*"))


def test_a_partition_with_other_columns_and_a_unit_outside_the_split_are_errors(tmp_path):
    """A parquet directory whose units disagree on their columns (a column one unit lacks
    vanished from every unit, or came back NaN) and a unit asked for outside the requested
    split (it was dropped without a word; the h5 reader refuses it) are one-line errors."""
    from engine_model.validation import InputError
    from tests.conftest import REPO

    df, meta = datasets.read_dataset(REPO / "data_samples" / "tiny", units=[1, 2])
    df = df[df["cycle"] <= 2]
    path = datasets.write_parquet(df, tmp_path / "d", {**meta, "dev_units": [1],
                                                       "test_units": [2]})
    with pytest.raises(InputError, match="not in the test split"):
        datasets.read_dataset(path, split="test", units=[1])
    back, _ = datasets.read_dataset(path, split="test", units=[2])
    assert set(back["unit"]) == {2}
    part = path / "unit=2" / "part-0.parquet"
    table = pq.read_table(part)
    pq.write_table(table.drop(["T48"]), part)
    with pytest.raises(InputError, match="T48"):
        datasets.read_dataset(path)


def test_effect_parameters_and_health_of_the_wrong_shape_are_refused():
    from engine_model import EngineModel
    from engine_model.physics.effects import parse_effect_spec
    from engine_model.validation import InputError

    m = EngineModel(effects=[parse_effect_spec("customer_bleed")], compiled=False)
    w = np.array([[0.0, 0.0, 100.0, 518.67]] * 2)
    with pytest.raises(InputError, match=r"p: shape \(3,\), expected \(2,\)"):
        m.solve(w, None, np.zeros(3))
    with pytest.raises(InputError, match=r"theta: shape \(9,\)"):
        m.solve(w, np.zeros(9))


def test_a_partition_storing_a_channel_as_text_names_file_column_and_row(tmp_path):
    """One unit's part file with a sensor stored as text (a hand-edited export): pyarrow's
    cast failed naming neither the file nor the row; the error names both."""
    from engine_model.validation import InputError
    from tests.conftest import REPO

    df, meta = datasets.read_dataset(REPO / "data_samples" / "tiny", units=[1, 2])
    df = df[df["cycle"] <= 2]
    path = datasets.write_parquet(df, tmp_path / "d", meta)
    part = path / "unit=2" / "part-0.parquet"
    table = pq.read_table(part)
    text = [f"{v}" for v in table.column("T30").to_pylist()]
    pq.write_table(table.set_column(table.schema.get_field_index("T30"), "T30",
                                    pa.array(text)).replace_schema_metadata(
                                        table.schema.metadata), part)
    back, _ = datasets.read_dataset(path)  # numbers as text: read as the numbers they are
    assert np.allclose(back["T30"], df["T30"])
    text[3] = "hot"
    pq.write_table(table.set_column(table.schema.get_field_index("T30"), "T30",
                                    pa.array(text)).replace_schema_metadata(
                                        table.schema.metadata), part)
    with pytest.raises(InputError, match=r"unit=2.*part-0.parquet: column T30, row 4: 'hot' "
                                         "is not a number"):
        datasets.read_dataset(path)
