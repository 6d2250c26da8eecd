"""``hyprog pipeline --augment`` on a simulated tiny fleet with an undeclared customer bleed
(f0 = 0.02): discover finds the bleed, the features stage recalibrates with it in the model,
and theta_hat against the truth improves from the base model's (biased by the bleed) to the
noise level. Marked slow: 4.5 minutes on the shared 2-core machine at load 6 (the simulation,
the candidate model and the recalibration each build an engine-model variant)."""

import json
import os
import subprocess
import sys

import pytest

CONFIG = """
[simulate]
preset = "tiny"
effects = ["customer_bleed:f0=0.02"]
[data]
units = [3, 4]
[discover]
candidates = ["customer_bleed"]
n_draws = 1000
[train]
model = "fnn"
epochs = 1
"""


@pytest.mark.slow
def test_augment_adds_the_found_bleed_and_recalibrates(tmp_path):
    cfg = tmp_path / "augment.toml"
    cfg.write_text(CONFIG)
    out = tmp_path / "out"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    r = subprocess.run([sys.executable, "-m", "cli.main", "pipeline", "--config", str(cfg),
                        "--augment", "--out", str(out), "--json"], env=env,
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    m = json.loads((out / "metrics.json").read_text())
    assert m["config"]["discover"]["augment"] is True
    found = m["discovery"]["found"]
    assert [f["effect"] for f in found] == ["customer_bleed"]
    f0, sd = found[0]["params"]["f0"], found[0]["std"]["f0"]
    assert abs(f0 - 0.02) < max(5 * sd, 1e-3), (f0, sd)
    assert m["features"]["effects"] == [found[0]["spec"]]
    base, aug = m["calibration"]["accuracy_base_model"], m["calibration"]["accuracy"]
    for q in ("HPT_eff_mod", "LPT_eff_mod", "LPT_flow_mod"):
        assert aug["overall"][q]["rmse"] < 0.005
        assert base["overall"][q]["rmse"] > 5 * aug["overall"][q]["rmse"]
    assert "Recalibrated with customer_bleed" in (out / "report.md").read_text()
    # the same run without --augment keeps the discovery but learns from the base model
    r = subprocess.run([sys.executable, "-m", "cli.main", "pipeline", "--config", str(cfg),
                        "--out", str(out), "--json"], env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    st = {k: v["status"] for k, v in json.loads(r.stdout)["stages"].items()}
    assert st["simulate"] == st["calibrate"] == st["discover"] == "skipped"
    assert st["features"] == st["train"] == st["evaluate"] == st["report"] == "done"
    assert json.loads((out / "metrics.json").read_text())["features"]["effects"] == []
