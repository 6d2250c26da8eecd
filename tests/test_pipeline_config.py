"""The pipeline's [train] table is derived from the library's TrainConfig (one definition of a
training option, so the two cannot drift apart), with the pipeline's own documented defaults."""

from dataclasses import fields

import pytest

from engine_model.validation import InputError
from prognostics.train_config import TrainConfig
from workflows.pipeline import config as pc


def test_every_train_config_field_is_a_train_key_unless_set_elsewhere():
    names = {f.name for f in fields(TrainConfig)}
    table = set(pc.SCHEMA["train"])
    assert table - set(pc.TRAIN_PIPELINE_KEYS) == names - set(pc.TRAIN_SET_ELSEWHERE)
    assert {"val_units", "val_fraction", "validation"} <= table  # were missing before


def test_defaults_are_the_library_s_except_the_documented_ones():
    lib = TrainConfig()
    d = pc.defaults()["train"]
    for key in set(d) - set(pc.TRAIN_PIPELINE_KEYS):
        want = pc.TRAIN_PIPELINE_DEFAULTS.get(key, getattr(lib, key))
        assert d[key] == want, key
    assert (d["epochs"], d["device"]) == (6, "cpu")


def test_train_config_carries_the_table_the_seed_and_the_split(tmp_path):
    toml = tmp_path / "p.toml"
    toml.write_text("[pipeline]\nseed = 7\n[train]\nval_units = [2]\nvalidation = \"units\"\n"
                    "max_rul = 125\nepochs = 2\n")
    cfg = pc.load_config(toml)
    tc = pc.train_config(cfg, "hybrid", {"dev": [1, 2, 3], "test": [4], "conformal": [3]})
    assert tc == TrainConfig(inputs="hybrid", seed=7, val_units=(2,), validation="units",
                             max_rul=125.0, epochs=2, device="cpu", units=(1, 2, 3),
                             test_units=(4,), conformal_units=(3,))


def test_a_field_set_elsewhere_is_an_unknown_key(tmp_path):
    toml = tmp_path / "p.toml"
    toml.write_text("[train]\nseed = 3\n")
    with pytest.raises(InputError, match=r"unknown key 'seed' in \[train\]"):
        pc.load_config(toml)
