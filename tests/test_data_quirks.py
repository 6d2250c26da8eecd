"""Quirks of users' data files that used to change data without a word or end in a traceback
(engine_model.datasets, ``hyprog data``, ``hyprog simulate``): each is refused in one line
naming the file and the line, row, column or key, or read as the file holds it.

The files are small and written by the tests.
"""

import json
import shutil
import warnings

import h5py
import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from cli.main import app
from engine_model.datasets import (
    output_format,
    parquet_unit_writer,
    read_cmapss,
    read_dataset,
    read_rul_file,
    write_ncmapss_h5,
    write_parquet,
    write_unit_part,
)
from engine_model.simulator import fleet
from engine_model.validation import InputError
from tests.cli_checks import assert_user_error, cli_runner
from tests.test_cmapss import line, write_lines


def table(units=(1, 1, 2, 2), cycles=(1, 2, 1, 2)):
    n = len(units)
    return pd.DataFrame({"unit": list(units), "cycle": list(cycles), "alt": np.zeros(n),
                         "Mach": np.zeros(n), "TRA": np.full(n, 100.0),
                         "T2": np.full(n, 518.67)})


def write_file(path, columns, meta=None):
    """A parquet file as another tool writes it: ``columns`` as given, optional metadata."""
    t = pa.table(columns)
    if meta is not None:
        t = t.replace_schema_metadata({b"hyprog": json.dumps(meta).encode()})
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(t, path)
    return path


def write_h5(path, units=(1.0, 1.0, 2.0, 2.0), attr=None):
    """A published-layout h5 file, float64 A; ``attr`` the raw ``hyprog`` attribute."""
    n = len(units)
    with h5py.File(path, "w") as f:
        f.create_dataset("W_var", data=np.array(["alt", "Mach", "TRA", "T2"], dtype="S"))
        f.create_dataset("A_var", data=np.array(["unit", "cycle", "Fc", "hs"], dtype="S"))
        f.create_dataset("W_dev", data=np.column_stack(
            [np.full(n, 1e4), np.full(n, 0.5), np.full(n, 80.0), np.full(n, 500.0)]))
        f.create_dataset("A_dev", data=np.column_stack(
            [np.asarray(units, float), np.arange(1.0, n + 1), np.ones(n), np.ones(n)]))
        if attr is not None:
            f.attrs["hyprog"] = attr
    return path


@pytest.fixture()
def strict():
    """numpy's overflow warnings (a silent wrap) become errors."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        yield


# 1. unit / cycle ids that a float or int64 cannot hold exactly ----------------------------
@pytest.mark.parametrize("token", ["10000000000000000000", "9223372036854775000",
                                   "9007199254740993"])
def test_cmapss_unit_beyond_2_53_is_refused_naming_the_line(tmp_path, strict, token):
    train = write_lines(tmp_path / "train_FD001.txt", [line(1, 1), line(token, 1)])
    with pytest.raises(InputError, match=rf"train_FD001.txt: line 2, column unit: {token} is"
                                         r" not an integer from 1 to 2\*\*53 - 1"):
        read_cmapss(train)


def test_parquet_ids_beyond_int64_or_2_53_are_refused_naming_the_row(tmp_path, strict):
    cols = {k: v.to_numpy() for k, v in table().items()}
    path = write_file(tmp_path / "u64.parquet",
                      {**cols, "unit": np.full(4, 2**64 - 1, dtype=np.uint64)})
    with pytest.raises(InputError, match="column unit = 18446744073709551615 at row 1 is"
                                         " larger than an int64 holds"):
        read_dataset(path)
    path = write_file(tmp_path / "f.parquet", {**cols, "cycle": np.array([1, 2, 3, 2.0**60])})
    with pytest.raises(InputError, match=r"column cycle = 1.15292e\+18 at row 4 is beyond"):
        read_dataset(path)
    ok = write_file(tmp_path / "u32.parquet", {**cols, "unit": np.array([3, 3, 4, 4], np.uint32)})
    assert read_dataset(ok)[0]["unit"].tolist() == [3, 3, 4, 4]


def test_h5_unit_beyond_2_53_is_refused_reading_and_writing(tmp_path, strict):
    with pytest.raises(InputError, match=r"A_dev, column unit = 1e\+19 at row 1 is beyond"):
        read_dataset(write_h5(tmp_path / "huge.h5", units=(1e19,) * 4))
    big = table().assign(unit=2**53 + 1)
    with pytest.raises(InputError, match=r"unit 9007199254740993 is beyond 2\*\*53 - 1"):
        write_ncmapss_h5(big, tmp_path / "big.h5")
    assert not (tmp_path / "big.h5").exists()
    write_parquet(big, tmp_path / "big")  # parquet keeps int64 exactly
    assert read_dataset(tmp_path / "big")[0]["unit"].iloc[0] == 2**53 + 1


# 2. a huge RUL ----------------------------------------------------------------------------
def test_a_huge_rul_is_refused_naming_the_line(tmp_path, strict):
    rul = write_lines(tmp_path / "RUL_FD001.txt", ["12 ", "1e20 "])
    with pytest.raises(InputError, match=r"RUL_FD001.txt: line 2, column RUL: 1e20 is not an"
                                         r" integer from 0 to 2\*\*53 - 1"):
        read_rul_file(rul)


# 3. line numbers of \r\r\n files ------------------------------------------------------------
def test_line_numbers_count_newlines_only(tmp_path):
    train = tmp_path / "train_FD001.txt"
    train.write_bytes("\r\r\n".join([line(1, 1), line(1, 2), line(1, 3), "abc", ""]).encode())
    with pytest.raises(InputError, match="train_FD001.txt: line 4: 1 columns"):
        read_cmapss(train)
    train.write_bytes("\r\r\n".join([line(1, 1), line(1, 2), ""]).encode())
    assert read_cmapss(train)[0]["cycle"].tolist() == [1, 2]


# 4. NaN unit in a parquet file ------------------------------------------------------------
def test_a_nan_unit_names_its_row_in_the_file(tmp_path, strict):
    cols = {k: v.to_numpy()[:3] for k, v in table().items()}
    write_file(tmp_path / "ds" / "data.parquet", {**cols, "unit": np.array([1.0, np.nan, 2.0])})
    for path in (tmp_path / "ds", tmp_path / "ds" / "data.parquet"):
        with pytest.raises(InputError, match="column unit is NaN, missing or not a number at"
                                             " row 2$"):
            read_dataset(path)


def test_a_cycle_below_one_names_its_unit_and_row_in_the_file(tmp_path, strict):
    """import-cmapss refuses it; a table written by other means is refused on reading, so
    calibrate and predict never count a cycle -1 as a flight."""
    cols = {k: v.to_numpy()[:3] for k, v in table().items()}
    write_file(tmp_path / "ds" / "data.parquet", {**cols, "cycle": np.array([1, 2, -1])})
    with pytest.raises(InputError, match=r"unit \d+, row 3, column cycle = -1: cycles count "
                                         r"flights from 1"):
        read_dataset(tmp_path / "ds")


# 5. pandas-written files: an index, a partitioned folder; a file without unit -------------
def test_pandas_written_parquet_is_read_as_the_file_holds_it(tmp_path):
    df = table()
    df.set_index("unit").to_parquet(tmp_path / "unit_index.parquet")
    (tmp_path / "indexed").mkdir()
    df.set_index("unit").to_parquet(tmp_path / "indexed" / "a.parquet")
    df.set_axis([10, 11, 12, 13]).to_parquet(tmp_path / "other_index.parquet")
    df.to_parquet(tmp_path / "partitioned", partition_cols=["unit"])
    for name in ("unit_index.parquet", "indexed", "other_index.parquet", "partitioned"):
        back, _ = read_dataset(tmp_path / name)
        assert back["unit"].tolist() == [1, 1, 2, 2] and back["cycle"].tolist() == [1, 2, 1, 2]
    runner = cli_runner()
    r = runner.invoke(app, ["data", "info", str(tmp_path / "partitioned"), "--json"])
    assert r.exit_code == 0 and json.loads(r.stdout)["totals"]["units"] == 2, r.stderr
    df.drop(columns="unit").to_parquet(tmp_path / "no_unit.parquet")
    r = runner.invoke(app, ["data", "info", str(tmp_path / "no_unit.parquet")])
    assert_user_error(r, "no_unit.parquet", "missing column(s) unit")


# 6. parquet files outside the dataset's layout --------------------------------------------
def test_a_copy_in_a_sub_folder_is_refused_not_read(tmp_path):
    ds = write_parquet(table(), tmp_path / "ds")
    shutil.copytree(ds / "unit=1", ds / ".hidden" / "unit=1")  # hidden: ignored
    assert len(read_dataset(ds)[0]) == 4
    shutil.copytree(ds / "unit=1", ds / "backup" / "unit=1")
    r = cli_runner().invoke(app, ["data", "info", str(ds)])
    assert_user_error(r, "backup/unit=1/part-0.parquet", "outside the dataset's layout")
    flat = tmp_path / "flat"
    table().to_parquet(write_file(flat / "sub" / "a.parquet", {"x": [1]}).parent.parent /
                       "data.parquet")
    with pytest.raises(InputError, match=r"sub/a.parquet: a parquet file outside"):
        read_dataset(flat)


# 7. the reserved column source_row --------------------------------------------------------
def test_a_source_row_column_is_refused_at_write_time(tmp_path):
    for write in (write_parquet, write_ncmapss_h5):
        out = tmp_path / ("s.h5" if write is write_ncmapss_h5 else "s")
        with pytest.raises(InputError, match="column source_row is reserved"):
            write(table().assign(source_row=1), out)
        assert not out.exists()


# 8. the dev/test split in a parquet writer's metadata -------------------------------------
def test_parquet_writers_check_the_split_as_the_h5_writer(tmp_path):
    for write in (write_parquet, write_ncmapss_h5):
        with pytest.raises(InputError, match="unit.s. 2 are in both dev_units and test_units"):
            write(table(), tmp_path / "a", {"dev_units": [1, 2], "test_units": [2]})
        with pytest.raises(InputError, match="unit.s. 2 are in neither dev_units nor"):
            write(table(), tmp_path / "b", {"dev_units": [1], "test_units": []})
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    # a listed unit the table lacks: the stored lists are those of the units written
    write_parquet(table(), tmp_path / "c", {"dev_units": [1, 9], "test_units": [2]})
    meta = read_dataset(tmp_path / "c", split="dev")[1]
    assert (meta["dev_units"], meta["test_units"]) == ([1], [2])
    with pytest.raises(InputError, match="unit.s. 2 are in neither"):
        write_unit_part(table().query("unit == 2"), tmp_path / "d", {"dev_units": [1],
                                                                     "test_units": []})
    with pytest.raises(InputError, match="unit.s. 1 are in both"):
        with parquet_unit_writer(tmp_path / "e", {"dev_units": [1], "test_units": [1]}) as w:
            w(table().query("unit == 1"))
    assert not (tmp_path / "d" / "unit=2").exists() and not (tmp_path / "e").exists()


# 9. / 10. metadata of the wrong type, an h5 sample rate that is not > 0 -------------------
@pytest.mark.parametrize("meta, fragment", [
    ({"dev_units": "1,2"}, "metadata dev_units must be a list of unit numbers"),
    ({"dev_units": [None]}, "metadata dev_units must be a list of unit numbers"),
    ({"test_units": [1.7]}, "metadata test_units must be a list of unit numbers"),
    ({"effects": 5}, "metadata effects must be a list"),
    ({"effects": {"x": 3}}, "metadata effects must be a list"),
    ({"sample_rate_hz": "abc"}, "metadata sample_rate_hz must be a finite number > 0"),
])
def test_wrongly_typed_metadata_is_one_line_naming_the_key(tmp_path, meta, fragment):
    cols = {k: v.to_numpy() for k, v in table().items()}
    path = write_file(tmp_path / "ds" / "data.parquet", cols, meta)
    assert_user_error(cli_runner().invoke(app, ["data", "info", str(path.parent)]),
                      "data.parquet", fragment)
    with pytest.raises(InputError, match=fragment):
        write_parquet(table(), tmp_path / "out", meta)


@pytest.mark.parametrize("attr, fragment", [
    (np.array([b"{}", b"{}"]), "the 'hyprog' attribute is an array of shape (2,)"),
    ('{"sample_rate_hz": 0}', "sample_rate_hz must be a finite number > 0 [Hz], got 0"),
    ('{"sample_rate_hz": -1}', "sample_rate_hz must be a finite number > 0 [Hz], got -1"),
    ('{"sample_rate_hz": Infinity}', "sample_rate_hz must be a finite number > 0"),
    ('{"sample_rate": NaN}', "sample_rate must be a finite number > 0"),
])
def test_h5_metadata_attribute_and_sample_rate_are_checked(tmp_path, strict, attr, fragment):
    path = write_h5(tmp_path / "f.h5", attr=attr)
    assert_user_error(cli_runner().invoke(app, ["data", "info", str(path)]), "f.h5", fragment)


# 11. --out suffix against --format ----------------------------------------------------------
def test_output_format_follows_the_suffix_and_refuses_a_contradiction():
    assert output_format("x.h5") == "h5" and output_format("x.HDF5") == "h5"
    assert output_format("x") == "parquet" and output_format("x.parquet") == "parquet"
    assert output_format("x.v2", "h5") == "h5"
    with pytest.raises(InputError, match="x.parquet: the suffix .parquet is for parquet, but"
                                         " --format is h5"):
        output_format("x.parquet", "h5", what="--format")
    with pytest.raises(InputError, match="x.h5: the suffix .h5 is for h5"):
        output_format("x.h5", "parquet")


def test_simulate_and_import_refuse_an_out_suffix_of_the_other_format(tmp_path):
    runner = cli_runner()
    out = tmp_path / "s.parquet"
    r = runner.invoke(app, ["simulate", "--units", "1", "--format", "h5", "--out", str(out)])
    assert_user_error(r, "s.parquet", "--format is h5")
    r = runner.invoke(app, ["simulate", "--units", "1", "--format", "parquet", "--out",
                            str(tmp_path / "s.h5")])
    assert_user_error(r, "s.h5", "--format is parquet")
    train = write_lines(tmp_path / "train_FD001.txt", [line(1, 1), line(1, 2)])
    r = runner.invoke(app, ["data", "import-cmapss", str(train), "--out", str(tmp_path / "x.h5")])
    assert_user_error(r, "x.h5", "the suffix .h5 is for h5")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["train_FD001.txt"]


def test_simulate_writes_h5_for_an_h5_out_without_format(tmp_path):
    out = tmp_path / "s.h5"
    r = cli_runner().invoke(app, ["simulate", "--units", "1", "--out", str(out), "--quiet"])
    assert r.exit_code == 0, r.stderr
    assert out.is_file() and h5py.is_hdf5(out)


# 12. the library simulator's seed ---------------------------------------------------------
@pytest.mark.parametrize("seed", [1.7, -1])
def test_library_simulate_checks_the_seed(tmp_path, seed):
    with pytest.raises(InputError, match=f"seed {seed}: expected an integer >= 0"):
        fleet.simulate("tiny", out=tmp_path / "f", units=[1], seed=seed)
    assert not (tmp_path / "f").exists()
