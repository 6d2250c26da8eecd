"""``hyprog pipeline`` through the CLI on two units of a freshly simulated tiny fleet (the
simulate stage; the same preset as the committed sample) with a reduced configuration (one
discrepancy candidate, a 3-epoch FNN): the report's files, resume (every
stage skipped), a changed option rerunning only its stage and those after it, an interrupted
run (SIGINT of a real process during training) leaving nothing half-written and resuming to
the numbers of an uninterrupted run, and bad input (one line, exit 2, nothing written).
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from html.parser import HTMLParser

import pytest
from typer.testing import CliRunner

from cli.main import app
from tests.conftest import REPO

CONFIG = """
[simulate]
preset = "tiny"
[data]
units = [3, 4]
[discover]
candidates = ["customer_bleed"]
n_draws = 1000
[train]
model = "fnn"
epochs = 3
"""
REPORT_FILES = ("report.md", "report.html", "metrics.json", "figures/theta.png",
                "figures/rul_data-driven.png", "figures/rul_hybrid.png",
                "figures/training.png", "figures/discrepancy.png", "figures/error_by_rul.png")
SECTIONS = ("Summary", "Fleet", "Calibration", "Model discrepancy", "Remaining useful life",
            "Timings", "Configuration", "Versions")
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def hyprog(*args, **kw):
    """Run the real console entry point in a subprocess (one torch thread)."""
    return subprocess.run([sys.executable, "-m", "cli.main", *map(str, args)], env=ENV,
                          capture_output=True, text=True, **kw)


def stages_of(stdout: str) -> dict:
    return {k: v["status"] for k, v in json.loads(stdout)["stages"].items()}


@pytest.fixture(scope="module")
def config(tmp_path_factory):
    path = tmp_path_factory.mktemp("cfg") / "pipeline.toml"
    path.write_text(CONFIG)
    return path


@pytest.fixture(scope="module")
def first_run(tmp_path_factory, config):
    out = tmp_path_factory.mktemp("runs") / "a"
    t0 = time.perf_counter()
    r = hyprog("pipeline", "--config", config, "--out", out, "--json")
    assert r.returncode == 0, r.stderr
    return out, json.loads(r.stdout), time.perf_counter() - t0


def test_run_writes_the_report(first_run):
    out, res, _ = first_run
    for f in REPORT_FILES:
        assert (out / f).is_file() and (out / f).stat().st_size > 0, f
    assert set(res["stages"]) == {"simulate", "data", "calibrate", "discover", "features", "train",
                                  "evaluate", "report"}
    assert all(v["status"] in ("done", "checked") for v in res["stages"].values())
    assert res["split"] == {"dev": [3], "test": [4], "conformal": [], "how": "metadata"}
    md = (out / "report.md").read_text()
    for section in ("## Fleet", "## Calibration", "## Model discrepancy",
                    "## Remaining useful life", "## Timings", "## Configuration",
                    "## Versions", "figures/rul_hybrid.png", "no conformal units"):
        assert section in md, section
    page = (out / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 6 and 'src="figures' not in page
    m = json.loads((out / "metrics.json").read_text())
    assert m["seed"] == 0 and m["config"]["train"]["epochs"] == 3
    assert set(m["rul"]) == {"data-driven", "hybrid"}
    assert set(m["rul"]["hybrid"]["samples"]["units"]) == {"4"}
    acc = m["calibration"]["accuracy"]["overall"]  # the tiny fleet carries the true theta
    assert set(acc) == {"HPT_eff_mod", "LPT_eff_mod", "LPT_flow_mod"}
    assert all(0 < v["rmse"] < 0.01 for v in acc.values())
    assert m["discovery"]["verdict"] in ("nothing missing", "explained", "partly explained",
                                         "unknown effect", "ambiguous")
    assert m["versions"]["hyprog"] and m["versions"]["torch"]
    assert "seconds" not in json.dumps(m)  # timings live in report.md and run.json


class _Page(HTMLParser):
    """The headings (in order) and table rows of an HTML page."""

    def __init__(self):
        super().__init__()
        self.h2, self.rows, self._tag, self._row = [], [], None, None

    def handle_starttag(self, tag, attrs):
        self._tag = tag
        if tag == "tr":
            self._row = []

    def handle_endtag(self, tag):
        if tag == "tr":
            self.rows.append(self._row)
        self._tag = None

    def handle_data(self, data):
        if self._tag == "h2":
            self.h2.append(data)
        elif self._tag in ("td", "th") and self._row is not None:
            self._row.append(data)


def test_the_html_report_opens_with_its_summary(first_run):
    """Issue 31: rendered HTML, parsed: the summary first, then the details in order; the
    summary's row for the test unit; the report's own time in the timings; no "all" row
    repeating the single test unit; figures at 150 dpi with their axes labelled."""
    from PIL import Image

    out, _, _ = first_run
    page = _Page()
    page.feed((out / "report.html").read_text())
    assert tuple(page.h2) == SECTIONS
    m = json.loads((out / "metrics.json").read_text())
    for inputs in ("data-driven", "hybrid"):
        last = m["rul"][inputs]["last"]["units"]["4"]
        row = next(r for r in page.rows if r[:2] == ["4", inputs])
        assert row[2] == str(last["cycle"]) and float(row[3]) == pytest.approx(
            last["RUL_pred"], rel=5e-3)
    assert any(r[0] == "report" and r[1] == "done" for r in page.rows)
    assert not any(len(r) > 1 and r[1] == "all" for r in page.rows)
    assert any(r[:2] == ["hybrid", "0.5"] for r in page.rows)  # α-λ at λ = 0.5
    md = (out / "report.md").read_text()
    assert md.index("## Summary") < md.index("## Fleet")
    assert "Model discrepancy: " in md and "Calibration (ukf)" in md
    for f in REPORT_FILES[3:]:
        dpi = Image.open(out / f).info["dpi"]
        assert dpi[0] == pytest.approx(150, abs=1), (f, dpi)
    for f in REPORT_FILES[3:]:  # read at 1280 px across: none is a thumbnail
        assert Image.open(out / f).size[0] >= 1200, f


def test_rerun_skips_every_stage(first_run, config):
    out, _, _ = first_run
    before = (out / "metrics.json").read_bytes()
    r = hyprog("pipeline", "--config", config, "--out", out, "--json")
    assert r.returncode == 0, r.stderr
    st = stages_of(r.stdout)
    assert {k: v for k, v in st.items() if k != "data"} == {
        k: "skipped" for k in ("simulate", "calibrate", "discover", "features", "train", "evaluate",
                               "report")}
    assert (out / "metrics.json").read_bytes() == before


def _interrupt_during_training(config, out):
    """Start a real run, SIGINT it one second into the train stage; (returncode, stderr)."""
    p = subprocess.Popen([sys.executable, "-m", "cli.main", "pipeline", "--config",
                          str(config), "--out", str(out)], env=ENV, stderr=subprocess.PIPE,
                         stdout=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        while not list(out.glob("stages/train-*")) and p.poll() is None \
                and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(1.0)  # inside the first network's epochs (about 1-2 s each)
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    return p.returncode, err


def test_interrupted_run_resumes_to_the_same_numbers(first_run, config, tmp_path):
    """SIGINT while the first network trains: exit 130 and the line ``error: interrupted``, no
    temporary, lock or half-written model left; the rerun redoes training only and its
    metrics.json equals the uninterrupted run's byte for byte (same seed, same numbers).
    The run starts from a copy of the uninterrupted run's stages before training, which are
    not run again; that a fresh run's stages reproduce their bytes in another process is
    tested by the interrupt tests of simulate and calibrate (tests/test_interrupts.py).

    A SIGINT whose exception a finalizer drops ("Exception ignored") is raised again by the
    entry point (cli.common.terminate_as_exit), so one attempt must give exit 130."""
    out = tmp_path / "b"
    # the first run's copy without its train stage and what follows it
    shutil.copytree(first_run[0], out)  # markers hold paths relative to the folder
    for stage in ("train", "evaluate", "report"):
        for folder in out.glob(f"stages/{stage}-*"):
            shutil.rmtree(folder)
    for f in REPORT_FILES:
        (out / f).unlink()
    code, err = _interrupt_during_training(config, out)
    assert code == 130, err
    assert err.strip().splitlines()[-1] == "error: interrupted", err
    left = [q for q in out.rglob("*") if ".tmp-" in q.name or ".old-" in q.name]
    assert not left, left
    assert not list(tmp_path.glob(".*hyprog-lock"))
    assert not list(out.glob("stages/train-*/stage.json"))
    assert not list(out.glob("stages/train-*/*/model.json"))  # no model was complete
    assert not (out / "metrics.json").exists()
    r = hyprog("pipeline", "--config", config, "--out", out, "--json")
    assert r.returncode == 0, r.stderr
    st = stages_of(r.stdout)
    assert st["simulate"] == st["calibrate"] == st["discover"] == st["features"] == "skipped"
    assert st["train"] == st["evaluate"] == st["report"] == "done"
    a = first_run[0]
    assert (out / "metrics.json").read_bytes() == (a / "metrics.json").read_bytes()


def test_changed_option_reruns_its_stage_and_those_after(first_run, config, tmp_path):
    out = tmp_path / "c"
    shutil.copytree(first_run[0], out)  # markers hold paths relative to the folder
    changed = tmp_path / "changed.toml"
    changed.write_text(config.read_text().replace("epochs = 3", "epochs = 2"))
    r = hyprog("pipeline", "--config", changed, "--out", out, "--json")
    assert r.returncode == 0, r.stderr
    st = stages_of(r.stdout)
    assert st["simulate"] == st["calibrate"] == st["discover"] == st["features"] == "skipped"
    assert st["train"] == st["evaluate"] == st["report"] == "done"
    assert len(list(out.glob("stages/train-*"))) == 1  # the old configuration's is gone
    m = json.loads((out / "metrics.json").read_text())
    assert m["training"]["hybrid"]["members"][0]["epochs_run"] == 2


# ----------------------------------------------------------------------------- bad input
@pytest.fixture(scope="module")
def runner():
    return CliRunner()


def assert_one_line_error(result, *fragments):
    assert result.exit_code == 2, (result.exit_code, result.stdout, result.stderr)
    err = result.stderr
    assert err.startswith("error: ") and len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err + result.stdout
    for f in fragments:
        assert f in err, (f, err)


def test_unknown_config_key_is_one_line_naming_key_and_file(runner, tmp_path):
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[train]\nepochz = 3\n")
    out = tmp_path / "out"
    r = runner.invoke(app, ["pipeline", "--config", str(cfg), "--out", str(out)])
    assert_one_line_error(r, "epochz", str(cfg), "[train]")
    assert not out.exists()
    cfg.write_text("[trian]\nepochs = 3\n")
    assert_one_line_error(runner.invoke(app, ["pipeline", "--config", str(cfg), "--out",
                                              str(out)]), "[trian]", str(cfg))
    cfg.write_text("[train]\nepochs = \"many\"\n")
    assert_one_line_error(runner.invoke(app, ["pipeline", "--config", str(cfg), "--out",
                                              str(out)]), "epochs", str(cfg))
    cfg.write_text("[train\n")
    assert_one_line_error(runner.invoke(app, ["pipeline", "--config", str(cfg), "--out",
                                              str(out)]), "not valid TOML", str(cfg))
    assert not out.exists()


@pytest.mark.parametrize("toml, fragments", [
    ("[train]\nepochs = -2\n", ["[train] epochs", "-2"]),
    ("[train]\nwindow = 0\n", ["[train] window", "0"]),
    ("[train]\nmax_rul = -5\n", ["[train] max_rul", "-5"]),
    ("[train]\nmax_rul = nan\n", ["[train] max_rul", "nan"]),
    ("[train]\nlr = -1\n", ["[train] lr", "-1"]),
    ("[train]\nbatch_size = 0\n", ["[train] batch_size", "0"]),
    ("[train]\ninputs = [\"bogus\"]\n", ["[train] inputs", "bogus", "input set"]),
    ("[train]\nmodel = \"similarity\"\ninputs = [\"health\"]\n",
     ["[train] inputs 'health'", "one health index"]),
    ("[train]\nmodel = \"similarity\"\ninputs = [\"HI_hat\"]\nensemble = 2\n",
     ["[train] ensemble = 2", "nothing random"]),
    ("[data]\ntest_units = [9]\n", ["[data] test_units", "9", "not in the data"]),
    ("[discover]\nalpha = 1.5\n", ["[discover] alpha", "1.5"]),
    ("[calibrate]\ndrift = -0.01\n", ["[calibrate] drift", "-0.01"]),
    ("[discover]\nenabled = false\naugment = true\n",
     ["[discover] augment = true with enabled = false"]),
    ("[simulate]\npreset = \"tiny\"\neffects = [\"customer_bleed\"]\n",
     ["[simulate]", "customer_bleed:f0="]),
    ("[simulate]\neffects = [\"customer_bleed:f0=0.02\"]\nseed = 3\n",
     ["[simulate] seed, effects set without preset", "nothing is simulated"]),
], ids=["epochs", "window", "max_rul", "max_rul-nan", "lr", "batch_size", "inputs",
        "similarity-inputs", "similarity-ensemble", "test_units", "alpha", "drift",
        "augment-without-discover", "neutral-effect", "simulate-without-preset"])
def test_bad_config_values_are_refused_before_any_stage(runner, tmp_path, toml, fragments):
    """Issue 31: these failed only after calibrate (and discover) ran, naming neither the file
    nor the key (``--alpha 1.5``, ``drift_std_per_sqrt_h``): now one line naming both, and
    nothing is left behind."""
    cfg = tmp_path / "bad.toml"
    cfg.write_text(toml)
    out = tmp_path / "out"
    r = runner.invoke(app, ["pipeline", "--config", str(cfg), "--out", str(out)])
    assert_one_line_error(r, str(cfg), *fragments)
    assert "drift_std_per_sqrt_h" not in r.stderr and "--alpha" not in r.stderr
    assert not out.exists()  # no stage ran: a refused run leaves nothing


def test_data_and_a_simulated_preset_together_are_refused(runner, tmp_path):
    cfg = tmp_path / "sim.toml"
    cfg.write_text('[simulate]\npreset = "tiny"\n')
    out = tmp_path / "out"
    tiny = REPO / "data_samples" / "tiny"
    r = runner.invoke(app, ["pipeline", str(tiny), "--config", str(cfg), "--out", str(out)])
    assert_one_line_error(r, str(cfg), "preset 'tiny' and DATA", "both given")
    assert not out.exists()


def test_missing_data_and_config_and_foreign_out(runner, tmp_path):
    out = tmp_path / "out"
    missing = tmp_path / "no-such-fleet"
    assert_one_line_error(runner.invoke(app, ["pipeline", str(missing), "--out", str(out)]),
                          str(missing))
    assert_one_line_error(runner.invoke(app, ["pipeline", "--config", str(tmp_path / "x.toml"),
                                              "--out", str(out)]), "x.toml")
    assert not out.exists()
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("keep me")
    assert_one_line_error(runner.invoke(app, ["pipeline", "--out", str(foreign)]),
                          str(foreign), "not a hyprog pipeline folder")
    assert [p.name for p in foreign.iterdir()] == ["thesis.tex"]
    assert not list(tmp_path.glob(".*hyprog-lock"))


def test_refused_data_leaves_nothing_behind(runner, tmp_path):
    """P30 in kPa (not psia): the calibrate stage refuses it before writing; the run exits 2
    with one line and the output folder it created is gone."""
    from engine_model.datasets import read_dataset, read_metadata, write_parquet
    from workflows.pipeline.stages import default_data

    df, _ = read_dataset(default_data(), units=[3, 4])
    data = tmp_path / "kpa"
    write_parquet(df.assign(P30=df["P30"] * 6.894757), data, read_metadata(default_data()))
    out = tmp_path / "out"
    r = runner.invoke(app, ["pipeline", str(data), "--out", str(out)])
    assert_one_line_error(r, str(data), "unit 3", "P30", "kPa")
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kpa"]


def test_a_test_unit_shorter_than_the_window_is_a_warning(tmp_path):
    """Issue 31: a pipeline whose test units are shorter than the window reported an RMSE
    over one left-padded sample with no word; now the JSON summary and the report's summary
    say so (unit 4 has 2,853 samples, unit 3 3,617; window 3,000)."""
    cfg = tmp_path / "short.toml"
    cfg.write_text("[data]\nunits = [3, 4]\n[discover]\nenabled = false\n[train]\n"
                   "model = \"cnn\"\nwindow = 3000\nepochs = 1\ninputs = [\"data-driven\"]\n")
    out = tmp_path / "out"
    r = hyprog("pipeline", "--config", cfg, "--out", out, "--json")
    assert r.returncode == 0, r.stderr
    said = json.loads(r.stdout)["warnings"]
    assert any("unit(s) 4 have fewer samples than the window (3000)" in w for w in said), said
    assert "Warning: data-driven: " in (out / "report.md").read_text()


def test_the_similarity_model_runs_through_the_pipeline(tmp_path):
    """A model that reads the flight table (here the similarity library on HI_hat) gets its
    inputs from the flight table at the features stage (the sample table has no health
    coordinates), and a model with no network has no training-curve figure."""
    cfg = tmp_path / "p.toml"
    cfg.write_text('[simulate]\npreset = "tiny"\n[data]\nunits = [3, 4]\n[discover]\n'
                   'enabled = false\n[train]\nmodel = "similarity"\nwindow = 5\n'
                   'inputs = ["HI_hat"]\n')
    r = hyprog("pipeline", "--config", cfg, "--out", tmp_path / "out", "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert stages_of(r.stdout)["train"] == "done"
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["features"]["inputs"] == {"HI_hat": ["HI_hat"]}
    assert (tmp_path / "out" / "figures" / "rul_HI_hat.png").is_file()
    assert not (tmp_path / "out" / "figures" / "training.png").exists()
    assert "no network: the library of the training units" in \
        (tmp_path / "out" / "report.md").read_text()
    assert rep["stages"]["evaluate"]["status"] == "done"
