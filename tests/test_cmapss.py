"""The C-MAPSS (2008) text files read into the hyprog table (engine_model.datasets.cmapss) and
``hyprog data import-cmapss``.

The files are written by the tests in the published layout: 26 space-separated numbers a line,
two trailing spaces (as in the NASA files), settings as in FD002 (altitude in kft).
"""

import json

import numpy as np
import pytest
from pandas.testing import assert_frame_equal

from cli.main import app
from engine_model.datasets import (
    CMAPSS_SENSORS,
    read_cmapss,
    read_cmapss_text,
    read_dataset,
    read_rul_file,
)
from engine_model.datasets.cmapss import (
    CONDITION_TOLERANCE,
    NOT_PHYSICAL,
    OPERATING_CONDITIONS,
    offset_for_test_units,
)
from engine_model.validation import InputError
from tests.cli_checks import assert_user_error, cli_runner

# an FD002 line: settings (alt kft, Mach, TRA) and the 21 sensors, T2 first, W32 last
SETTINGS = (34.9983, 0.84, 100.0)
SENSORS = (449.44, 555.32, 1358.61, 1137.23, 5.48, 7.97, 194.64, 2222.65, 8341.91, 1.02,
           42.02, 183.06, 2387.72, 8048.56, 9.3461, 0.02, 334, 2223, 100.00, 14.73, 8.8071)
TRAIN_CYCLES = {1: 4, 2: 3}
TEST_CYCLES = {1: 2, 2: 3}
TEST_RUL = (112, 98)


def line(unit, cycle, alt_kft=SETTINGS[0], sensors=SENSORS):
    """One line of a C-MAPSS file: sensors drift with the cycle so every row differs."""
    values = [alt_kft, *SETTINGS[1:], *(s + 0.01 * cycle for s in sensors)]
    return f"{unit} {cycle} " + " ".join(f"{v:.4f}" for v in values) + "  "


def write_lines(path, lines):
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture()
def files(tmp_path):
    train = write_lines(tmp_path / "train_FD002.txt",
                        [line(u, c) for u, n in TRAIN_CYCLES.items() for c in range(1, n + 1)])
    test = write_lines(tmp_path / "test_FD002.txt",
                       [line(u, c) for u, n in TEST_CYCLES.items() for c in range(1, n + 1)])
    rul = write_lines(tmp_path / "RUL_FD002.txt", [f"{r} " for r in TEST_RUL])
    return train, test, rul


@pytest.fixture(scope="module")
def runner():
    return cli_runner()


# ---------------------------------------------------------------------------------------------
# library
# ---------------------------------------------------------------------------------------------

def test_columns_map_in_the_documented_order_and_altitude_is_in_feet(files):
    df = read_cmapss_text(files[0])
    assert list(df.columns) == ["unit", "cycle", "alt", "Mach", "TRA", "condition",
                                *CMAPSS_SENSORS]
    assert CMAPSS_SENSORS[:4] == ("T2", "T24", "T30", "T50")
    assert CMAPSS_SENSORS[-2:] == ("W31", "W32")
    assert len(df) == sum(TRAIN_CYCLES.values())
    first = df.iloc[0]
    assert first["alt"] == pytest.approx(34998.3)  # 34.9983 kft
    assert (first["Mach"], first["TRA"]) == (0.84, 100.0)
    for name, value in zip(CMAPSS_SENSORS, SENSORS, strict=True):
        assert first[name] == pytest.approx(value + 0.01, abs=1e-9), name
    assert df["unit"].dtype == np.int64 and df["cycle"].dtype == np.int64


def test_train_rul_counts_down_to_zero_at_the_last_cycle(files):
    df, meta = read_cmapss(files[0])
    u1 = df[df["unit"] == 1]
    assert u1["cycle"].tolist() == [1, 2, 3, 4]
    assert u1["RUL"].tolist() == [3, 2, 1, 0]
    assert df[df["unit"] == 2]["RUL"].tolist() == [2, 1, 0]
    assert df["RUL"].dtype == np.int64
    assert (df["t"] == 0.0).all() and df["t"].dtype == np.float64
    assert meta == {"source_format": "cmapss-text", "dev_units": [1, 2], "test_units": [],
                    "test_unit_offset": 1000, "source_files": {"train": "train_FD002.txt"},
                    "cmapss_subset": "FD002", "not_physical": NOT_PHYSICAL,
                    "settings_snapped": {"train": {}},
                    "conditions": {"centres": [list(c) for c in OPERATING_CONDITIONS],
                                   "tolerance": list(CONDITION_TOLERANCE), "rows": {"5": 7}},
                    "constant_channels": [], "constant_channels_by_condition": {"5": []}}
    assert "sample_rate_hz" not in meta  # one snapshot per cycle: no sample rate
    assert list(df.columns[:8]) == ["unit", "cycle", "t", "RUL", "alt", "Mach", "TRA", "T2"]


def test_calibration_leaves_the_not_physical_ps30_out_by_default(files):
    from calibration import CalibrationSetup

    df, meta = read_cmapss(files[0])
    assert list(meta["not_physical"]) == ["Ps30"]
    default = CalibrationSetup().for_dataset(meta)
    used = default.resolve_sensors(df.columns)
    assert "Ps30" not in used and {"T24", "T30", "T50", "P30", "Nf", "Nc"} <= set(used)
    chosen = CalibrationSetup(sensors=("T30", "Ps30")).for_dataset(meta)  # the user decides
    assert chosen.resolve_sensors(df.columns) == ("T30", "Ps30")
    assert CalibrationSetup().for_dataset({}) == CalibrationSetup()


def test_test_units_are_renumbered_and_their_rul_comes_from_the_rul_file(files):
    df, meta = read_cmapss(*files)
    assert meta["dev_units"] == [1, 2] and meta["test_units"] == [1001, 1002]
    assert meta["source_files"] == {"train": "train_FD002.txt", "test": "test_FD002.txt",
                                    "rul": "RUL_FD002.txt"}
    assert sorted(df["unit"].unique()) == [1, 2, 1001, 1002]
    # the trajectory stops RUL_file cycles before failure: RUL = RUL_file + last - cycle
    assert df[df["unit"] == 1001]["RUL"].tolist() == [112 + 1, 112]
    assert df[df["unit"] == 1002]["RUL"].tolist() == [98 + 2, 98 + 1, 98]
    assert df[df["unit"] == 1]["RUL"].tolist() == [3, 2, 1, 0]  # train units unchanged
    assert df["unit"].is_monotonic_increasing


def test_test_unit_offset_clears_every_train_unit():
    assert offset_for_test_units([1, 260]) == 1000
    assert offset_for_test_units([999]) == 1000
    assert offset_for_test_units([1000]) == 2000
    assert offset_for_test_units([2500]) == 3000


def test_rul_file_reads_one_integer_a_line(tmp_path):
    path = write_lines(tmp_path / "RUL.txt", ["112 ", "98", "", "69  "])
    assert read_rul_file(path).tolist() == [112, 98, 69]
    with pytest.raises(InputError, match=r"line 2, column RUL: 9.5 is not an integer"):
        read_rul_file(write_lines(tmp_path / "bad.txt", ["3", "9.5"]))


@pytest.mark.parametrize("bad_line, fragments", [
    ("1 5 " + "1.0 " * 23, ("line 8", "25 columns", "expected 26")),
    (line(1, 5).replace("1358.6600", "hot"), ("line 8", "column T30", "'hot'")),
    (line(1, 5).replace("2222.7000", "NaN"), ("line 8", "column Nf", "NaN")),
    (line(1, 5).replace("1 5 ", "1 5.5 ", 1), ("line 8", "column cycle", "5.5")),
])
def test_bad_lines_are_named_by_file_line_and_column(files, bad_line, fragments):
    train = files[0]  # 7 good lines, the bad one is line 8
    with train.open("a") as fh:
        fh.write(bad_line + "\n")
    with pytest.raises(InputError) as info:
        read_cmapss(train)
    message = str(info.value)
    assert message.startswith(str(train))
    for f in fragments:
        assert f in message, (f, message)


def test_rul_file_length_must_match_the_test_units(files, tmp_path):
    train, test, _ = files
    short = write_lines(tmp_path / "RUL_short.txt", ["112 "])
    with pytest.raises(InputError, match=r"1 RUL values, but test_FD002.txt has 2 test units"):
        read_cmapss(train, test, short)
    with pytest.raises(InputError, match="needs its RUL file"):
        read_cmapss(train, test)


@pytest.mark.parametrize("edit, message", [
    # a cycle repeated, going back, skipping one: the RUL is counted back from the last cycle
    (lambda rows: rows[:3] + [rows[2]] + rows[3:], r"line 4, unit 1: cycle 3 appears twice "
     r"\(line 3 too\)"),
    (lambda rows: rows[:3] + [rows[1]] + rows[3:], r"line 4, unit 1: cycle 2 after "
     r"cycle 3"),
    (lambda rows: rows[:2] + rows[3:], r"line 3, unit 1: cycle 4 after cycle 2 \(cycles must "
     r"increase by one\)"),
    # unit 1 again at the end, after unit 2: it would be merged across a gap
    (lambda rows: rows + [line(1, 99)], r"unit 1 again, after other units \(its rows began "
     r"at line 1\)"),
])
def test_a_unit_out_of_order_is_refused_naming_the_line(tmp_path, edit, message):
    rows = [line(u, c) for u, n in TRAIN_CYCLES.items() for c in range(1, n + 1)]
    bad = write_lines(tmp_path / "train_FD002.txt", edit(rows))
    with pytest.raises(InputError, match=message):
        read_cmapss(bad)


# ---------------------------------------------------------------------------------------------
# hyprog data import-cmapss
# ---------------------------------------------------------------------------------------------

def test_import_writes_a_parquet_dataset_that_reads_back(runner, files, tmp_path):
    out = tmp_path / "fd002"
    train, test, rul = files
    r = runner.invoke(app, ["data", "import-cmapss", str(train), "--test", str(test), "--rul",
                            str(rul), "--out", str(out), "--json"])
    assert r.exit_code == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["rows"] == 12 and rep["test_units"] == [1001, 1002]
    expected, meta = read_cmapss(train, test, rul)
    back, back_meta = read_dataset(out)
    assert_frame_equal(back, expected, check_exact=True)
    assert {k: back_meta[k] for k in meta} == meta
    test_only, _ = read_dataset(out, split="test")
    assert sorted(test_only["unit"].unique()) == [1001, 1002]
    info = json.loads(runner.invoke(app, ["data", "info", str(out), "--json"]).stdout)
    assert info["source_format"] == "cmapss-text"
    # the test units fail after their last cycle: last cycle + RUL (2 + 112, 3 + 98)
    assert [u["eol"] for u in info["units"]] == [4, 3, 114, 101]


def test_import_errors_are_one_line_and_leave_nothing(runner, files, tmp_path):
    train, test, rul = files
    out = tmp_path / "out"
    r = runner.invoke(app, ["data", "import-cmapss", str(train), "--test", str(test),
                            "--out", str(out)])
    assert_user_error(r, "--test", "--rul")
    short = write_lines(tmp_path / "RUL_short.txt", ["112"])
    r = runner.invoke(app, ["data", "import-cmapss", str(train), "--test", str(test),
                            "--rul", str(short), "--out", str(out)])
    assert_user_error(r, str(short), "1 RUL values", "2 test units")
    r = runner.invoke(app, ["data", "import-cmapss", str(tmp_path / "nope.txt"), "--out",
                            str(out)])
    assert_user_error(r, "nope.txt", "no such file")
    with train.open("a") as fh:
        fh.write("1 5 " + "1.0 " * 25 + "\n")
    r = runner.invoke(app, ["data", "import-cmapss", str(train), "--test", str(test), "--rul",
                            str(rul), "--out", str(out)])
    assert_user_error(r, str(train), "line 8", "27 columns")
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == [
        "RUL_FD002.txt", "RUL_short.txt", "test_FD002.txt", "train_FD002.txt"]


def test_an_empty_file_is_an_error(tmp_path):
    empty = write_lines(tmp_path / "train_FD001.txt", ["   "])
    with pytest.raises(InputError, match="no data lines"):
        read_cmapss(empty)


# ---------------------------------------------------------------------------------------------
# the quirks of the real files (written here: the NASA files are never in the project)
# ---------------------------------------------------------------------------------------------

# an FD001-like row at sea-level static, TRA 100: the settings' noise puts Mach and altitude
# slightly below zero on some rows, as in the published train_FD001.txt
FD001_SENSORS = (518.67, 641.82, 1589.70, 1400.60, 14.62, 21.61, 554.36, 2388.06, 9046.19,
                 1.30, 47.47, 521.66, 2388.02, 8138.62, 8.4195, 0.03, 392, 2388, 100.00,
                 39.06, 23.4190)
CONSTANT_FD001 = ("T2", "P2", "epr", "farB", "Nf_dmd", "PCNfR_dmd")


def fd001_line(unit, cycle, alt_kft, mach, tra=100.0):
    """A line with FD001's constant channels constant and every other sensor drifting."""
    sensors = [s if name in CONSTANT_FD001 else s + 0.01 * cycle
               for name, s in zip(CMAPSS_SENSORS, FD001_SENSORS, strict=True)]
    return (f"{unit} {cycle} {alt_kft:.4f} {mach:.4f} {tra:.1f} "
            + " ".join(f"{v:.4f}" for v in sensors) + "  ")


def test_real_file_quirks_crlf_trailing_spaces_and_noisy_settings(tmp_path):
    """CRLF line endings, two trailing spaces and settings noise below zero (Mach -0.0006,
    altitude -0.0087 kft): read as they are, Mach snapped to the envelope's 0 and recorded."""
    rows = [fd001_line(1, 1, -0.0007, -0.0004), fd001_line(1, 2, 0.0019, -0.0006),
            fd001_line(1, 3, -0.0087, 0.0003), fd001_line(2, 1, 0.0, 0.0)]
    path = tmp_path / "train_FD001.txt"
    path.write_bytes(("\r\n".join(rows) + "\r\n").encode())
    df, meta = read_cmapss(path)
    assert len(df) == 4
    assert df["Mach"].tolist() == [0.0, 0.0, 0.0003, 0.0]
    assert df["alt"].tolist() == pytest.approx([-0.7, 1.9, -8.7, 0.0])  # inside the envelope
    assert meta["settings_snapped"] == {"train": {"Mach": {"rows": 2, "max_shift": 0.0006}}}
    assert df["condition"].tolist() == [1, 1, 1, 1] and df["condition"].dtype == np.int64
    assert meta["conditions"]["rows"] == {"1": 4}
    assert meta["constant_channels"] == list(CONSTANT_FD001)
    assert meta["constant_channels_by_condition"] == {"1": list(CONSTANT_FD001)}
    assert df["T24"].tolist() == pytest.approx([641.83, 641.84, 641.85, 641.83])


@pytest.mark.parametrize("setting,values,fragment", [
    ("Mach", (0.0, -0.02), "column Mach: -0.02 is outside the flight envelope [0, 0.9]"),
    ("alt", (-1.7, 0.0), "column alt: -1.7 kft is outside the flight envelope [-1500, 45000] ft"),
    ("TRA", (0.0, 0.0, 107.0), "column TRA: 107 is outside the flight envelope [15, 105]"),
])
def test_a_setting_beyond_its_noise_is_an_error_naming_line_and_column(tmp_path, setting,
                                                                       values, fragment):
    alt, mach, tra = {"Mach": (0.0, values[1], 100.0), "alt": (values[0], 0.0, 100.0),
                      "TRA": (0.0, 0.0, values[2] if len(values) > 2 else 100.0)}[setting]
    path = write_lines(tmp_path / "train_FD001.txt",
                       [fd001_line(1, 1, 0.0, 0.0), fd001_line(1, 2, alt, mach, tra)])
    with pytest.raises(InputError) as e:
        read_cmapss(path)
    assert str(e.value).startswith(f"{path}: line 2, {fragment}")


def test_a_sensor_reading_that_is_not_positive_names_line_and_column(tmp_path):
    bad = list(SENSORS)
    bad[2] = -5.0  # T30
    path = write_lines(tmp_path / "train_FD001.txt", [line(1, 1), line(1, 2, sensors=bad)])
    with pytest.raises(InputError) as e:
        read_cmapss(path)
    assert str(e.value).startswith(f"{path}: line 2, column T30: -4.98 is not positive")


def test_the_six_operating_conditions_are_labelled_and_others_are_zero(tmp_path):
    noise = (0.008, -0.002, 0.0)  # FD002's largest setting noise
    lines = [fd001_line(1, k + 1, a + noise[0], max(m + noise[1], 0.0), tra)
             for k, (a, m, tra) in enumerate(OPERATING_CONDITIONS)]
    lines.append(fd001_line(1, 7, 30.0, 0.5, 80.0))  # not a C-MAPSS condition
    df, meta = read_cmapss(write_lines(tmp_path / "train_FD002.txt", lines))
    assert df["condition"].tolist() == [1, 2, 3, 4, 5, 6, 0]
    assert meta["conditions"]["rows"] == {str(k): 1 for k in range(7)}
    # no two conditions within twice the tolerance: a row is never at two
    c = np.asarray(OPERATING_CONDITIONS)
    gap = np.abs(c[:, None, :] - c[None]) > 2 * np.asarray(CONDITION_TOLERANCE)
    assert all(gap[i, j].any() for i in range(6) for j in range(6) if i != j)


def test_import_then_calibrate_runs_on_a_noisy_sea_level_file(runner, tmp_path):
    """What stopped every real FD001 / FD003 import at calibration (Mach -0.0004 on row 1)
    now runs: import-cmapss, then calibrate, unchanged."""
    rows = [fd001_line(1, c, (-1) ** c * 0.004, -0.0004 if c % 2 else 0.0002)
            for c in range(1, 4)]
    train = write_lines(tmp_path / "train_FD001.txt", rows)
    data, feats = tmp_path / "fd001", tmp_path / "features"
    r = runner.invoke(app, ["data", "import-cmapss", str(train), "--out", str(data)])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["calibrate", str(data), "--out", str(feats), "--json"])
    assert r.exit_code == 0, r.output
    df, _ = read_dataset(feats)
    assert len(df) == 3 and df["HPT_eff_mod_hat"].notna().all()
    # NASA's Ps30 is in the data and left out (not physical), not "absent"
    rep = json.loads(r.stdout)
    assert "Ps30" in rep["sensors_left_out"] and "Ps30" not in rep["sensors_absent"]


def test_import_calibrate_train_evaluate_run_unchanged_on_six_conditions(runner, tmp_path):
    """The chain a new user runs on FD002: import (noisy settings of six conditions),
    calibrate, train (Li et al.'s DCNN, per-condition standardisation chosen by itself,
    constant channels dropped), evaluate held-out units at their last cycle."""
    import pandas as pd

    from data_samples import sample_path

    means = pd.read_csv(sample_path("cmapss-fd002-operating-points.csv"))  # NASA's six points
    noise = (0.008, -0.002, 0.0)
    lines = []
    for u in range(1, 5):
        for c in range(1, 13):
            k = (u + c) % 6
            a, m, tra = OPERATING_CONDITIONS[k]
            point = means.iloc[k]
            sensors = [point[n] if n in point.index else s  # farB, htBleed, Nf_dmd: FD001's
                       for n, s in zip(CMAPSS_SENSORS, FD001_SENSORS, strict=True)]
            sensors = [v * (1 + 1e-4 * c * (n in ("T30", "T50", "Ps30")))  # wear
                       for n, v in zip(CMAPSS_SENSORS, sensors, strict=True)]
            lines.append(f"{u} {c} {a + noise[0] * (-1) ** c:.4f} {max(m + noise[1], 0.0):.4f} "
                         f"{tra:.1f} " + " ".join(f"{v:.4f}" for v in sensors) + "  ")
    train = write_lines(tmp_path / "train_FD002.txt", lines)
    data, feats, model = tmp_path / "fd002", tmp_path / "features", tmp_path / "model"
    r = runner.invoke(app, ["data", "import-cmapss", str(train), "--out", str(data)])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["calibrate", str(data), "--out", str(feats), "--quiet"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["train", str(feats), "--model", "dcnn", "--window", "5",
                            "--inputs", "w+cmapss+theta_hat", "--units", "1,2,3",
                            "--val-units", "3", "--max-rul", "125", "--epochs", "2",
                            "--batch-size", "16", "--lr", "0.002", "--out", str(model),
                            "--json"])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    # per condition, every channel but the worn ones is constant in the written file
    assert {"P2", "farB", "Nf_dmd", "T24"} <= set(rep["dropped_constant"])  # T2: a setting
    assert "T30" not in rep["dropped_constant"]
    assert rep["batch_size"] == 16 and rep["validation"] == "units"
    from prognostics.checkpoint import load_model

    assert load_model(model).config.normalise == "condition"
    r = runner.invoke(app, ["evaluate", str(model), str(feats), "--units", "4", "--json"])
    assert r.exit_code == 0, r.output
    last = json.loads(r.stdout)["last"]["units"]["4"]
    assert last["cycle"] == 12 and 0.0 <= last["RUL_pred"] <= 125.0


def noisy_fd002_lines(units=4, cycles=12, seed=0):
    """FD002-like lines at NASA's six operating points with per-engine offsets and noise of a
    known size on every sensor but P2 (one value per condition, as in the real files)."""
    import pandas as pd

    from data_samples import sample_path

    rng = np.random.default_rng(seed)
    means = pd.read_csv(sample_path("cmapss-fd002-operating-points.csv"))
    lines = []
    for u in range(1, units + 1):
        offset = rng.normal(0.0, 5e-4, len(CMAPSS_SENSORS))
        for c in range(1, cycles + 1):
            k = (u + c) % 6
            a, m, tra = OPERATING_CONDITIONS[k]
            point = means.iloc[k]
            sensors = [point[n] if n in point.index else s
                       for n, s in zip(CMAPSS_SENSORS, FD001_SENSORS, strict=True)]
            sensors = [v if n in ("P2", *CONSTANT_FD001)
                       else v * (1 + offset[j] + 1e-3 * rng.standard_normal())
                       for j, (n, v) in enumerate(zip(CMAPSS_SENSORS, sensors, strict=True))]
            lines.append(f"{u} {c} {a:.4f} {m:.4f} {tra:.1f} "
                         + " ".join(f"{v:.4f}" for v in sensors) + "  ")
    return lines


def test_calibrate_with_the_datas_own_noise_per_condition(runner, tmp_path):
    """``--noise data``: each sensor's std per operating condition from the data (within
    engines, early life) is the R of the filter, recorded in the metadata; P2 (one value per
    condition) is left out; the model's own error adds in quadrature; a resumed run agrees."""
    from calibration import CalibrationSetup
    from calibration.calibrate_fleet import with_data_noise
    from calibration.measurement_noise import noise_from_data
    from calibration.series import prepare_unit
    from engine_model.datasets import read_metadata

    train = write_lines(tmp_path / "train_FD002.txt", noisy_fd002_lines())
    data, feats = tmp_path / "fd002", tmp_path / "features"
    assert runner.invoke(app, ["data", "import-cmapss", str(train), "--out",
                               str(data)]).exit_code == 0
    r = runner.invoke(app, ["calibrate", str(data), "--out", str(feats), "--noise", "data",
                            "--quiet"])
    assert r.exit_code == 0, r.output
    setup = read_metadata(feats)["calibration"]["setup"]
    assert setup["noise"] == "data" and "P2" in setup["exclude_sensors"]
    df, _ = read_dataset(data)
    used = sorted({ch for _, ch, _ in setup["noise_table"]})
    assert "P2" not in used and {"T24", "T30", "T50", "P30", "Nc"} <= set(used)
    expected = noise_from_data(df, used)
    for c, ch, std in setup["noise_table"]:
        assert std == pytest.approx(expected.loc[c, ch], rel=1e-12)
    assert runner.invoke(app, ["calibrate", str(data), "--out", str(feats), "--noise", "data",
                               "--quiet"]).exit_code == 0  # resumed: the same settings
    # the filter's R: the table at each row's condition, times --noise-scale, with the model's
    # own error in quadrature
    base = with_data_noise(CalibrationSetup(noise="data", sensors=tuple(used)), df, "data")
    unit = df[df["unit"] == 1].reset_index(drop=True)
    for scale, me in ((1.0, 0.0), (2.0, 0.001)):
        s = prepare_unit(unit, CalibrationSetup(**{**base.__dict__, "noise_scale": scale,
                                                   "model_error": me}))
        want = scale * expected.loc[unit["condition"], used].to_numpy()
        want = np.hypot(want, me * unit[used].to_numpy())
        np.testing.assert_allclose(s.sigma, want, rtol=1e-12)


def test_data_noise_needs_an_operating_condition_label(runner, tmp_path):
    from calibration import CalibrationSetup
    from calibration.calibrate_fleet import calibrate_fleet

    train = write_lines(tmp_path / "train_FD002.txt", noisy_fd002_lines(units=2, cycles=12))
    df, _ = read_cmapss(train)
    with pytest.raises(InputError, match="no column 'condition'"):
        calibrate_fleet(df.drop(columns="condition"), setup=CalibrationSetup(noise="data"))
    with pytest.raises(InputError, match="noise must be 'model' or 'data'"):
        CalibrationSetup(noise="measured")
    with pytest.raises(InputError, match=r"must be in \[0, 0.1\)"):
        CalibrationSetup(model_error=0.5)
    data = tmp_path / "fd002"
    assert runner.invoke(app, ["data", "import-cmapss", str(train), "--out",
                               str(data)]).exit_code == 0
    r = runner.invoke(app, ["calibrate", str(data), "--out", str(tmp_path / "f"), "--noise",
                            "data", "--sensors", "T30,P2"])
    assert_user_error(r, "P2", "no noise to estimate", code=None)
    assert not (tmp_path / "f").exists()


def test_the_flow_channels_are_read_with_the_datas_noise_and_refused_without(runner,
                                                                            tmp_path):
    """C-MAPSS's bypass ratio and coolant flows (model outputs outside x_s) are sensors of a
    calibration with the data's noise: estimated per condition like the others, and recorded
    with the sensors used. The simulator documents no noise for them, so without ``--noise
    data`` they are refused with one line naming them; the MHE, whose compiled NLP reads x_s
    only, refuses them too."""
    from calibration import CalibrationSetup
    from calibration.mhe import MHEEstimator
    from engine_model.datasets import read_metadata

    train = write_lines(tmp_path / "train_FD002.txt", noisy_fd002_lines(units=3, cycles=12))
    data, feats = tmp_path / "fd002", tmp_path / "features"
    assert runner.invoke(app, ["data", "import-cmapss", str(train), "--out",
                               str(data)]).exit_code == 0
    flows = "T24,T30,T50,P15,P30,Nc,BPR,W31,W32"
    r = runner.invoke(app, ["calibrate", str(data), "--out", str(tmp_path / "refused"),
                            "--sensors", flows])
    assert_user_error(r, "BPR, W31, W32", "--noise data", code=None)
    assert not (tmp_path / "refused").exists()
    r = runner.invoke(app, ["calibrate", str(data), "--out", str(feats), "--noise", "data",
                            "--sensors", flows, "--quiet"])
    assert r.exit_code == 0, r.output
    meta = read_metadata(feats)
    assert meta["calibration"]["setup"]["sensors"] == flows.split(",")
    in_table = {ch for _, ch, _ in meta["calibration"]["setup"]["noise_table"]}
    assert {"BPR", "W31", "W32"} <= in_table
    df, _ = read_dataset(feats)
    assert np.isfinite(df["HPT_eff_mod_hat"]).all()
    with pytest.raises(InputError, match="unknown sensor.*BPR2"):
        CalibrationSetup(noise="data", sensors=("T30", "BPR2"))
    r = runner.invoke(app, ["calibrate", str(data), "--out", str(tmp_path / "mhe"), "--method",
                            "mhe", "--noise", "data", "--sensors", "T30,BPR"])
    assert_user_error(r, "mhe: reads the measured channels x_s only, not BPR", code=None)
    assert not (tmp_path / "mhe").exists()
    with pytest.raises(InputError, match="x_s only, not W31"):
        MHEEstimator.check_setup(CalibrationSetup(noise="data", sensors=("T30", "W31")))


def test_the_pipeline_calibrates_with_the_datas_noise_and_a_consistent_model_error(runner,
                                                                                    tmp_path):
    """``[calibrate] noise = "data"``, ``model_error = "consistent"``: the pipeline's feature
    table records the data's noise table and the model error the search found; a value that
    is neither a number nor 'consistent' is a one-line error naming the table."""
    from engine_model.datasets import read_metadata

    train = write_lines(tmp_path / "train_FD002.txt", noisy_fd002_lines(units=4, cycles=12))
    data = tmp_path / "fd002"
    assert runner.invoke(app, ["data", "import-cmapss", str(train), "--out",
                               str(data)]).exit_code == 0
    config = tmp_path / "p.toml"
    config.write_text('[data]\ndev_units = [1, 2, 3]\ntest_units = [4]\n'
                      '[calibrate]\nnoise = "data"\nmodel_error = "consistent"\n'
                      '[discover]\ncandidates = ["inlet_loss"]\n'
                      '[train]\nmodel = "dcnn"\nwindow = 4\nepochs = 1\ninputs = ["hybrid"]\n')
    out = tmp_path / "run"
    r = runner.invoke(app, ["pipeline", str(data), "--config", str(config), "--out", str(out),
                            "--quiet"])
    assert r.exit_code == 0, r.output
    features = next(out.glob("stages/calibrate-*/features"))
    setup = read_metadata(features)["calibration"]["setup"]
    assert setup["noise"] == "data" and setup["noise_table"] and setup["model_error"] > 0
    # the discover stage: the calibrate stage's R and sensors
    found = json.loads(next(out.glob("stages/discover-*/report/discover.json")).read_text())
    assert not {"P2", "Ps30", "phi"} & set(found["diagnostics"]["sensors"])
    config.write_text('[calibrate]\nmodel_error = "often"\n')
    r = runner.invoke(app, ["pipeline", str(data), "--config", str(config), "--out",
                            str(tmp_path / "never")])
    assert_user_error(r, "[calibrate]", "'consistent'", code=None)


def test_discover_on_measured_data_uses_calibrates_r_and_sensors(runner, tmp_path):
    """``hyprog discover --noise data``: the data's noise per condition, and the sensors
    ``calibrate`` would use (the not-physical Ps30 and phi and the noiseless P2 left out);
    the pipeline's discover stage takes its calibrate stage's R the same way."""
    train = write_lines(tmp_path / "train_FD002.txt", noisy_fd002_lines(units=4, cycles=12))
    data = tmp_path / "fd002"
    assert runner.invoke(app, ["data", "import-cmapss", str(train), "--out",
                               str(data)]).exit_code == 0
    r = runner.invoke(app, ["discover", str(data), "--out", str(tmp_path / "rep"), "--noise",
                            "data", "--model-error", "0.001", "--candidates", "inlet_loss",
                            "--json"])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    used = rep["diagnostics"]["sensors"]
    assert not {"P2", "Ps30", "phi"} & set(used) and {"T30", "T50", "P30"} <= set(used)
    # one sample per flight: each held-out flight's residual has m - k degrees of freedom
    # (its own theta fitted), not minus every flight's theta (which left none)
    b = rep["before"]
    assert b["on"] == "held-out flights"
    k, m = len(rep["diagnostics"]["params"]), len(used)
    rms = sum(c["rmse"] ** 2 for c in b["channels"].values())
    assert b["chi2_per_dof"] == pytest.approx(rms / (m - k), rel=1e-9)
    plain = runner.invoke(app, ["discover", str(data), "--out", str(tmp_path / "rep2"),
                                "--candidates", "inlet_loss", "--json"])
    assert plain.exit_code == 0, plain.output
    assert "Ps30" not in json.loads(plain.stdout)["diagnostics"]["sensors"]
    bad = runner.invoke(app, ["discover", str(data), "--out", str(tmp_path / "rep3"),
                              "--model-error", "often"])
    assert_user_error(bad, "--model-error often", code=None)
