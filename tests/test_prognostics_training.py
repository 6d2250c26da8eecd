"""The paper's networks, reproducible training, ensembles and conformal intervals through
``fit``, and the checkpoint (round trip; tampered, foreign and other-version files).

Synthetic feature tables (tests/conftest.py); every training run is a few epochs of seconds.
"""

import json
import warnings

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from engine_model.validation import InputError
from prognostics.checkpoint import MANIFEST, load_model, save_model, sha256_bytes
from prognostics.ensemble import RulModel, fit
from prognostics.models import CNN1D, FNN, SameConv1d, build_model, parameter_count
from prognostics.train_config import TrainConfig

pytestmark = pytest.mark.usefixtures("torch_one_thread")

# ---------------------------------------------------------------------------------------------
# networks
# ---------------------------------------------------------------------------------------------


def test_parameter_counts_of_the_papers_description():
    # FNN [n, 200, 200, 200, 50, 1]: (n + 1) 200 + 2 * 201 * 200 + 201 * 50 + 51
    assert parameter_count(build_model("fnn", 20, 1)) == 21 * 200 + 2 * 201 * 200 + 201 * 50 + 51
    assert parameter_count(build_model("fnn", 20, 1)) == 94_701  # the paper's "95k"
    # CNN: (10 n + 1) 10 + 2 * 101 * 10 ... see prognostics.models
    assert parameter_count(build_model("cnn", 20, 50)) == 5_722
    assert parameter_count(build_model("cnn", 50, 50)) == 8_722  # not the paper's "24k"


def test_cnn_keeps_the_window_length_with_papers_same_padding():
    torch.manual_seed(0)
    conv = SameConv1d(3, 2, 10)
    x = torch.randn(4, 3, 50)
    ref = F.conv1d(F.pad(x, (4, 5)), conv.weight, conv.bias)  # 4 zeros left, 5 right
    torch.testing.assert_close(conv(x), ref)
    odd = SameConv1d(3, 2, 7)
    torch.testing.assert_close(odd(x), F.conv1d(F.pad(x, (3, 3)), odd.weight, odd.bias))
    # the channels-last computation has Conv1d's gradients too; compared in double precision,
    # since the two kernels sum 200 products per weight in different orders (in float32 that
    # alone differs by ~1e-5 relative)
    conv, x = conv.double(), x.double()
    ref = F.conv1d(F.pad(x, (4, 5)), conv.weight, conv.bias)
    g = torch.autograd.grad(conv(x).square().sum(), (conv.weight, conv.bias))
    g_ref = torch.autograd.grad(ref.square().sum(), (conv.weight, conv.bias))
    for a, b in zip(g, g_ref, strict=True):
        torch.testing.assert_close(a, b)
    net = build_model("cnn", 7, 30, seed=0)
    assert isinstance(net, CNN1D) and net(torch.randn(5, 7, 30)).shape == (5,)
    assert isinstance(build_model("fnn", 7, 1, seed=0), FNN)
    with pytest.raises(InputError, match="FNN takes one time step"):
        build_model("fnn", 7, 50)
    with pytest.raises(InputError, match="unknown model"):
        build_model("lstm", 7, 50)


def test_xavier_init_is_seeded():
    a, b, c = (build_model("cnn", 5, 20, seed=s) for s in (1, 1, 2))
    for (k, va), vb, vc in zip(a.state_dict().items(), b.state_dict().values(),
                               c.state_dict().values(), strict=True):
        assert torch.equal(va, vb), k
        if k.endswith("bias"):
            assert not va.any()
        else:
            assert not torch.equal(va, vc)


# ---------------------------------------------------------------------------------------------
# training
# ---------------------------------------------------------------------------------------------

TINY = dict(batch_size=64, device="cpu")


def _weights_equal(m1: RulModel, m2: RulModel) -> bool:
    return all(torch.equal(m1.members[0].state[k], m2.members[0].state[k])
               for k in m1.members[0].state)


@pytest.mark.parametrize("model,window", [("fnn", None), ("cnn", 10)])
def test_tiny_training_lowers_the_loss_and_is_bit_identical_for_a_seed(make_features, model,
                                                                       window):
    df, meta = make_features()
    cfg = TrainConfig(model=model, inputs="hybrid", window=window, epochs=6, seed=4,
                      patience=10, **TINY)
    a = fit(df, meta, cfg)
    h = a.members[0].history
    assert len(h) == 6
    assert h[-1]["train_loss"] < 0.5 * h[0]["train_loss"], h
    assert min(r["val_loss"] for r in h) < h[0]["val_loss"]
    b = fit(df, meta, cfg)
    assert _weights_equal(a, b)
    strip = [{k: v for k, v in r.items() if k != "seconds"} for r in h]
    assert strip == [{k: v for k, v in r.items() if k != "seconds"}
                     for r in b.members[0].history]
    pa, pb = a.predict(df, [5, 6]), b.predict(df, [5, 6])
    assert np.array_equal(pa["RUL_pred"].to_numpy(), pb["RUL_pred"].to_numpy())
    other = fit(df, meta, TrainConfig(model=model, inputs="hybrid", window=window, epochs=6,
                                      seed=5, patience=10, **TINY))
    assert not _weights_equal(a, other)


def test_early_stopping_restores_the_best_validation_epoch(make_features):
    df, meta = make_features()
    m = fit(df, meta, TrainConfig(model="fnn", inputs="data-driven", epochs=40, patience=2,
                                  lr=0.05, seed=0, **TINY))
    h = m.members[0].history
    vals = [r["val_loss"] for r in h]
    best = int(np.argmin(vals)) + 1
    assert m.members[0].best_epoch == best
    assert len(h) == best + 2 < 40  # stopped after `patience` epochs without improvement
    # the restored weights are the best epoch's: their validation loss is the recorded one
    from prognostics.splits import VALIDATION
    from prognostics.training import predict_windows, prepare

    prep = prepare(df, meta, m.config)
    val = prep.windows[VALIDATION]
    pred = predict_windows(m.networks()[0], val, torch.device("cpu"))
    mse = float(np.mean((pred - val.target.double().numpy()) ** 2))
    assert mse == pytest.approx(vals[best - 1], rel=1e-6)


def test_ensemble_spread_conformal_units_and_max_rul(make_features):
    df, meta = make_features()
    cfg = TrainConfig(model="cnn", inputs="hybrid", window=8, epochs=3, seed=0,
                      conformal_units=(4,), alpha=0.2, max_rul=15.0, **TINY)
    m = fit(df, meta, cfg, seeds=[0, 1, 2])
    assert [x.seed for x in m.members] == [0, 1, 2]
    assert m.conformal is not None and m.conformal.units == (4,)
    n4 = int((df.unit == 4).sum()) - (8 - 1)  # unit 4's windows (one segment)
    assert m.conformal.n_scores == n4
    p = m.predict(df, [5, 6])
    assert {"RUL_pred", "RUL_std", "RUL_lower", "RUL_upper"} <= set(p.columns)
    assert np.all(p["RUL_std"] > 0)
    np.testing.assert_allclose(p["RUL_upper"] - p["RUL_pred"], m.conformal.quantile)
    assert np.all(p["RUL_lower"] >= 0)
    metrics, _ = m.evaluate(df, [5, 6])
    inside = (p["RUL"] >= p["RUL_lower"]) & (p["RUL"] <= p["RUL_upper"])
    assert metrics["samples"]["overall"]["coverage"] == pytest.approx(inside.mean(), abs=1e-12)
    with pytest.raises(InputError, match="unit.* 4 are both development and test"):
        fit(df, meta, TrainConfig(model="fnn", test_units=(4,), units=(1, 2, 3, 4),
                                  epochs=1, **TINY))


def test_a_unit_shorter_than_the_window_gets_one_padded_prediction(make_features):
    df, meta = make_features()
    m = fit(df, meta, TrainConfig(model="cnn", inputs="data-driven", window=30, epochs=1,
                                  **TINY))
    short = df[(df.unit == 5) & (df.cycle == 1)]  # fewer than 30 samples
    assert len(short) < 30
    with pytest.warns(UserWarning, match=r"unit\(s\) 5 have fewer samples than the window"):
        p = m.predict(short)
    assert len(p) == 1 and p["t"].iloc[0] == short["t"].max()
    full = m.predict(df, [6])
    assert len(full) == int((df.unit == 6).sum()) - 29  # the first 29 samples have no window


def test_predict_names_a_missing_input_column(make_features):
    df, meta = make_features()
    m = fit(df, meta, TrainConfig(model="fnn", inputs="hybrid", epochs=1, **TINY))
    with pytest.raises(InputError, match="data.parquet: missing input column.*LPT_eff_mod_hat"):
        m.predict(df.drop(columns="LPT_eff_mod_hat"), source="data.parquet")


# ---------------------------------------------------------------------------------------------
# checkpoint
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    from tests.conftest import synthetic_features

    df, meta = synthetic_features()
    m = fit(df, meta, TrainConfig(model="cnn", inputs="hybrid", window=8, epochs=2,
                                  conformal_units=(4,), **TINY), seeds=[0, 1])
    path = save_model(m, tmp_path_factory.mktemp("ckpt") / "model")
    return m, path, df


def _copy(src, tmp_path):
    import shutil

    dst = tmp_path / "copy"
    shutil.copytree(src, dst)
    return dst


def test_checkpoint_round_trip(trained, tmp_path):
    m, path, df = trained
    assert sorted(p.name for p in path.iterdir()) == [
        "member-0.safetensors", "member-1.safetensors", MANIFEST]
    body = json.loads((path / MANIFEST).read_text())
    assert body["config"]["window"] == 8 and body["columns"] == list(m.columns)
    assert body["hyprog_version"] and body["scaler"]["columns"] == list(m.columns)
    # what the bits depend on besides seed and data (prognostics.training)
    # (the thread count of the fixture's training, which the tests' fixtures may set)
    assert body["trained_with"]["torch"] == torch.__version__
    assert body["trained_with"]["device"] == "cpu"
    assert isinstance(body["trained_with"]["threads"], int) \
        and body["trained_with"]["threads"] >= 1
    back = load_model(path)
    assert back.info["trained_with"] == body["trained_with"]
    assert back.columns == m.columns and back.config == m.config
    assert back.conformal == m.conformal
    assert back.scaler.to_dict() == m.scaler.to_dict()
    for a, b in zip(m.members, back.members, strict=True):
        assert a.seed == b.seed and a.history == b.history
        assert all(torch.equal(a.state[k], b.state[k]) for k in a.state)
    pa, pb = m.predict(df, [5]), back.predict(df, [5])
    assert np.array_equal(pa["RUL_pred"].to_numpy(), pb["RUL_pred"].to_numpy())
    # the weights are plain safetensors: torch.load of a pickle is never needed
    from safetensors.torch import load_file

    assert set(load_file(path / "member-0.safetensors")) == set(m.members[0].state)
    # saving again over a model directory replaces it; anything else is refused
    save_model(back, path)
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "keep.txt").write_text("mine")
    with pytest.raises(InputError, match="not a hyprog model directory; not replacing"):
        save_model(m, tmp_path / "notes")
    assert (tmp_path / "notes" / "keep.txt").read_text() == "mine"


def test_save_removes_what_a_killed_writer_left(trained, tmp_path):
    """A writer killed by SIGKILL leaves its hidden temporary; the next save under that folder
    removes it (its process is gone) and keeps a running writer's (this process's)."""
    from engine_model.runtime.atomic import temporary_prefix

    m = trained[0]
    dead = tmp_path / (temporary_prefix("model").rsplit("-", 2)[0] + "-999999999-x")
    running = tmp_path / (temporary_prefix("other") + "y")
    for d in (dead, running):
        d.mkdir()
        (d / "member-0.safetensors").write_bytes(b"half")
    path = save_model(m, tmp_path / "model")
    assert not dead.exists() and running.exists()
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == [running.name]
    assert load_model(path).members[0].seed == m.members[0].seed


def test_tampered_weights_are_refused(trained, tmp_path):
    _, path, _ = trained
    d = _copy(path, tmp_path)
    blob = bytearray((d / "member-1.safetensors").read_bytes())
    blob[-1] ^= 0x01  # one bit of one weight
    (d / "member-1.safetensors").write_bytes(bytes(blob))
    with pytest.raises(InputError, match=r"member-1\.safetensors: SHA-256 mismatch"):
        load_model(d)


def test_weights_swapped_between_members_are_refused(trained, tmp_path):
    _, path, _ = trained
    d = _copy(path, tmp_path)
    a, b = (d / "member-0.safetensors").read_bytes(), (d / "member-1.safetensors").read_bytes()
    (d / "member-0.safetensors").write_bytes(b)
    (d / "member-1.safetensors").write_bytes(a)
    with pytest.raises(InputError, match="SHA-256 mismatch"):
        load_model(d)


def test_an_edited_manifest_is_refused(trained, tmp_path):
    _, path, _ = trained
    d = _copy(path, tmp_path)
    body = json.loads((d / MANIFEST).read_text())
    body["scaler"]["maximum"][0] += 1.0
    (d / MANIFEST).write_text(json.dumps(body))
    with pytest.raises(InputError, match="model.json: SHA-256 mismatch"):
        load_model(d)


def resign_manifest(d, drop=(), **changes):
    """Change (or ``drop``) manifest fields and re-sign it as the checkpoint docstring specifies
    (SHA-256 of the canonical JSON: sorted keys, no spaces), as another hyprog would have
    written it."""
    body = json.loads((d / MANIFEST).read_text())
    body.pop("sha256")
    for key in drop:
        body.pop(key)
    body.update(changes)
    canonical = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False)
    body["sha256"] = sha256_bytes(canonical.encode())
    (d / MANIFEST).write_text(json.dumps(body))


def test_the_model_records_the_thread_count_it_was_trained_with(make_features,
                                                                torch_one_thread):
    df, meta = make_features()
    m = fit(df, meta, TrainConfig(model="fnn", inputs="data-driven", epochs=1, **TINY))
    assert m.info["trained_with"] == {"torch": torch.__version__, "device": "cpu",
                                      "threads": 1}


def test_a_model_written_before_trained_with_was_recorded_loads(trained, tmp_path):
    _, path, _ = trained
    d = _copy(path, tmp_path)
    resign_manifest(d, drop=("trained_with",))
    assert load_model(d).info["trained_with"] is None


def test_evaluating_a_unit_used_in_training_warns(trained, tmp_path):
    """The model records the units of each role in training; evaluating one of them warns
    (its error is not a test error), and a model written before they were recorded loads
    and evaluates without the warning."""
    import warnings

    from tests.conftest import synthetic_features

    m, path, df = trained
    back = load_model(path)
    assert back.info["units"] == m.info["units"]
    assert m.info["units"]["conformal"] == [4]
    train_unit = m.info["units"]["training"][0]
    with pytest.warns(UserWarning, match=rf"unit\(s\) {train_unit} were used to train this "
                      r"model \(training\): their error is not a test error"):
        back.evaluate(df, [train_unit])
    held = sorted(set(df["unit"].unique()) - {u for us in m.info["units"].values()
                                               for u in us})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back.evaluate(df, held)  # the test units: no warning
    # validation on flights: a unit both trains and validates, and the warning names both
    df2, meta2 = synthetic_features()
    flights = fit(df2, meta2, TrainConfig(model="fnn", inputs="data-driven", epochs=1,
                                          validation="flights", **TINY))
    both = sorted(set(flights.info["units"]["training"])
                  & set(flights.info["units"]["validation"]))
    assert both
    with pytest.warns(UserWarning, match=r"\(training, validation\)"):
        flights.evaluate(df2, both[:1])
    d = _copy(path, tmp_path)
    resign_manifest(d, drop=("units",))
    old = load_model(d)
    assert old.info["units"] is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        old.evaluate(df, [train_unit])


def test_inputs_far_outside_the_training_range_warn(trained):
    """An FD001 model given FD002's six conditions predicted 0 everywhere without a word:
    inputs more than one training range beyond it warn, naming the columns."""
    import warnings

    m, _, df = trained
    held = [5]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m.predict(df, held)
    far = df.copy()
    col = m.columns[0]
    lo, hi = m.scaler.minimum[0], m.scaler.maximum[0]
    far[col] = hi + 2.5 * (hi - lo)
    with pytest.warns(UserWarning, match=rf"input column\(s\) {col} lie beyond the training "
                      "range"):
        m.predict(far, held)


def test_foreign_files_are_refused(trained, tmp_path):
    _, path, _ = trained
    with pytest.raises(InputError, match="no such model directory"):
        load_model(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="not a hyprog model directory"):
        load_model(tmp_path / "empty")
    (tmp_path / "pickle").mkdir()
    torch.save({"w": torch.zeros(3)}, tmp_path / "pickle" / MANIFEST)
    with pytest.raises(InputError, match="not a hyprog model manifest"):
        load_model(tmp_path / "pickle")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / MANIFEST).write_text(json.dumps({"format": "keras", "layers": []}))
    with pytest.raises(InputError, match="format is not 'hyprog-prognostics'"):
        load_model(tmp_path / "other")
    with pytest.raises(InputError, match="not a hyprog model directory"):
        load_model(path / "member-0.safetensors")


def test_another_format_version_is_refused(trained, tmp_path):
    _, path, _ = trained
    d = _copy(path, tmp_path)
    resign_manifest(d, format_version=99, hyprog_version="9.9.9")
    with pytest.raises(InputError, match="model format version 99 .* retrain"):
        load_model(d)


def test_another_hyprog_version_loads_with_a_warning(trained, tmp_path):
    m, path, df = trained
    d = _copy(path, tmp_path)
    resign_manifest(d, hyprog_version="0.0.1")
    with pytest.warns(UserWarning, match="written by hyprog 0.0.1"):
        back = load_model(d)
    assert back.info["hyprog_version"] == "0.0.1"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_model(path)  # the current version: no warning


def test_weights_that_do_not_fit_the_network_are_refused(trained, tmp_path):
    _, path, _ = trained
    d = _copy(path, tmp_path)
    body = json.loads((d / MANIFEST).read_text())
    cfg = dict(body["config"], window=9)
    resign_manifest(d, config=cfg)
    with pytest.raises(InputError, match="weights do not fit"):
        load_model(d)


def test_prediction_progress_counts_every_window_and_changes_nothing():
    from prognostics.training import predict_windows
    from prognostics.windows import make_windows

    x = np.arange(300, dtype=np.float32).reshape(100, 3) / 300.0
    win = make_windows(x, np.array([0, 40]), np.array([40, 100]), length=10)
    net = build_model("cnn", 3, 10, seed=0)
    seen = []
    with_bar = predict_windows(net, win, torch.device("cpu"), batch=16, progress=seen.append)
    assert sum(seen) == len(win) and max(seen) == 16
    plain = predict_windows(net, win, torch.device("cpu"), batch=16)
    np.testing.assert_array_equal(with_bar, plain)


def test_max_rul_caps_the_training_targets(make_features):
    """``max_rul`` (``--max-rul``): the piecewise-linear target min(RUL, cap) of every window
    in every role; without it the targets are the table's RUL."""
    from prognostics.splits import TRAIN
    from prognostics.training import prepare

    df, meta = make_features()
    capped = prepare(df, meta, TrainConfig(model="fnn", max_rul=15.0, **TINY))
    free = prepare(df, meta, TrainConfig(model="fnn", **TINY))
    for role, w in capped.windows.items():
        y, y0 = w.target.numpy(), free.windows[role].target.numpy()
        np.testing.assert_array_equal(y, np.minimum(y0, 15.0))
    assert free.windows[TRAIN].target.numpy().max() > 15.0  # the cap is reached


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the refusal on a CPU machine")
def test_cuda_requested_without_a_gpu_is_a_clear_error():
    from prognostics.training import resolve_device

    with pytest.raises(InputError, match="no CUDA device available"):
        resolve_device("cuda")
    assert resolve_device("auto").type == "cpu"
    with pytest.raises(InputError, match="auto, cpu or cuda"):
        resolve_device("gpu")


def test_a_network_stopped_by_the_epoch_cap_while_improving_is_named():
    """FD003 with the defaults: best epoch 248 of 250 (patience 77), so the cap ended the
    training, not early stopping; `hyprog train` says so (a larger --epochs may help). A
    best epoch more than half the patience before the cap is a converged run: not named."""
    from prognostics.training import Member

    def member(seed, losses):
        hist = [{"epoch": i + 1, "train_loss": v, "val_loss": v} for i, v in enumerate(losses)]
        return Member(seed, {}, hist, int(np.nanargmin(losses)) + 1, 1)

    cfg = TrainConfig(model="fnn", inputs="hybrid", epochs=10, patience=4)
    falling = member(0, [10.0 - i for i in range(10)])  # best at the last epoch
    early = member(1, [5.0, 4.0, 3.0, 3.5, 3.6, 3.7, 3.8])  # stopped early: patience reached
    flat_end = member(2, [9, 8, 7, 6, 5, 4, 3, 2, 2.5, 2.6])  # best 8: 2 epochs before the cap
    late = member(3, [9, 8, 7, 6, 5, 4, 3, 2, 1, 1.1])  # best 9 of 10: within half patience
    model = RulModel(cfg, ("a",), None, [falling, early, flat_end, late])
    assert model.still_improving() == [
        "seed 0: training used all 10 epochs and the validation loss was still improving "
        "(best epoch 10): a larger --epochs may give a better network",
        "seed 3: training used all 10 epochs and the validation loss was still improving "
        "(best epoch 9): a larger --epochs may give a better network"]
    no_val = Member(4, {}, [{"epoch": i + 1, "train_loss": 1.0, "val_loss": None}
                            for i in range(10)], 10, 1)
    assert RulModel(cfg, ("a",), None, [no_val]).still_improving() == []
