"""The public surface of each package (issue 31): the names a script imports exist, are
documented and typed (``py.typed`` in every package); the typed objects refuse what they
cannot do with one clear error."""

import importlib

import pytest

from engine_model.validation import InputError
from tests.conftest import REPO

SURFACE = {
    "engine_model.datasets": ("Dataset", "load_sample", "read_dataset", "write_dataset"),
    "calibration": ("calibrate", "CalibrationSetup", "FleetRun"),
    "calibration.discrepancy": ("discover", "DiscoverOptions", "Discovery"),
    "prognostics": ("RulEstimator", "Evaluation", "RulModel", "TrainConfig", "fit",
                    "load_model", "save_model", "evaluate_predictions", "resolve_inputs"),
}


@pytest.mark.parametrize("module", sorted(SURFACE))
def test_the_public_names_exist_and_are_documented(module):
    mod = importlib.import_module(module)
    for name in SURFACE[module]:
        assert name in mod.__all__, (module, name)
        obj = getattr(mod, name)
        assert (obj.__doc__ or "").strip(), f"{module}.{name} has no docstring"


def test_every_package_is_typed():
    for package in ("engine_model", "calibration", "prognostics", "workflows", "cli",
                    "data_samples"):
        assert (REPO / package / "py.typed").is_file(), package


def test_importing_prognostics_does_not_import_torch():
    import subprocess
    import sys

    code = "import sys, prognostics; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"


def test_dataset_split_and_selection():
    from engine_model.datasets import load_sample

    fleet = load_sample()
    assert fleet.units == [1, 2, 3, 4]
    assert fleet.dev_units == [1, 2, 3] and fleet.test_units == [4]
    assert fleet.test().units == [4] and fleet.development().units == [1, 2, 3]
    assert [int(f["unit"].iloc[0]) for f in fleet.unit_frames()] == [1, 2, 3, 4]
    with pytest.raises(InputError, match=r"unit\(s\) 9 not in the table"):
        fleet.select([9])
    bare = type(fleet)(fleet.frame, {})
    with pytest.raises(InputError, match="names no test_units"):
        bare.test()


def test_estimator_refuses_what_it_cannot_do():
    from prognostics import RulEstimator

    with pytest.raises(InputError, match="unknown option.*epoch"):
        RulEstimator(epoch=3)
    with pytest.raises(InputError, match="window must be >= 1"):
        RulEstimator(window=0)
    with pytest.raises(InputError, match="ensemble must be >= 1"):
        RulEstimator(ensemble=0)
    est = RulEstimator(model="fnn")
    with pytest.raises(InputError, match="not fitted"):
        est.predict(None)
    assert "not fitted" in repr(est) and "model='fnn'" in repr(est)


def test_cli_choices_are_the_librarys():
    """The CLI lists its choices without importing the library (fast --help); they must be
    the library's own names."""
    import typing

    import typer

    from calibration.base import ESTIMATORS
    from cli.main import app
    from prognostics.train_config import MODEL_KINDS

    def choices(command, name):
        param = next(p for p in command.params if p.name == name)
        return typing.get_args(param.type_descriptor.annotation)

    root = typer.main.get_command(app)
    assert choices(root.commands["calibrate"].commands["run"], "method") == tuple(ESTIMATORS)
    assert set(choices(root.commands["discover"], "method")) == {"coarse", *ESTIMATORS}
    assert choices(root.commands["train"], "model") == MODEL_KINDS


def test_caught_warnings_keeps_the_librarys_and_passes_the_others_on():
    """``cli.common.caught_warnings``: the library's UserWarnings once each, in order, for the
    report; any other category (a dependency's RuntimeWarning) handed back to Python."""
    import warnings

    from cli.common import caught_warnings

    with warnings.catch_warnings(record=True) as outer:
        warnings.simplefilter("always")
        with caught_warnings() as said:
            warnings.warn("first", UserWarning, stacklevel=1)
            warnings.warn("overflow", RuntimeWarning, stacklevel=1)
            warnings.warn("first", UserWarning, stacklevel=1)
            warnings.warn("second", UserWarning, stacklevel=1)
    assert said == ["first", "second"]
    assert [str(w.message) for w in outer] == ["overflow"]
