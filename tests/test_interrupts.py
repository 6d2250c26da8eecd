"""Interrupted commands (issue 15), through the real console entry point in a subprocess:

- SIGINT (Ctrl-C) and SIGTERM end a command with one line, ``error: interrupted`` /
  ``error: terminated``, exit 130 / 143, and leave neither the output, a temporary nor the lock;
- a SIGKILL of ``hyprog simulate`` or ``hyprog calibrate`` in the middle of its run (after its
  first unit was written, before the last) leaves no half-written final file (hidden
  temporaries or a hidden partial fleet at most), and the rerun, which continues from the
  complete units, gives the files of an uninterrupted run byte for byte.

The uninterrupted runs are the library's, in this process (the shared compiled model), and so
is the calibration's rerun, so each test costs one or two command starts. Data: the tiny
preset's units 3 and 4 (simulate, a few seconds each) and a cut of the committed tiny fleet
(calibrate): unit 3's first two cycles and unit 4's first five, so that with ``--jobs 2`` unit
3's task ends well before unit 4's (the kill lands between them).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from engine_model import datasets
from engine_model.runtime.lock import lock_path
from tests.conftest import REPO

TINY = REPO / "data_samples" / "tiny"
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
DRIFT = "0.01"  # the tiny fleet's fast wear (README)


def start(*args) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "cli.main", *map(str, args)], cwd=REPO,
                            env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def hyprog(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cli.main", *map(str, args)], cwd=REPO,
                          env=ENV, capture_output=True, text=True)


def wait_for(proc: subprocess.Popen, ready, what: str, timeout: float = 240) -> None:
    """Poll ``ready()`` every 20 ms until true; fail if the process ended first."""
    deadline = time.monotonic() + timeout
    while not ready():
        assert proc.poll() is None, (what, proc.returncode, proc.stderr.read())
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


def signal_and_wait(proc: subprocess.Popen, sig: int) -> tuple[int, str]:
    try:
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, err


def hidden(folder: Path, name: str, kind: str = "tmp") -> list[Path]:
    """The hidden temporaries (``kind="tmp"``) or partial fleets (``"partial"``) of ``name``
    in ``folder``."""
    return sorted(folder.glob(f".{name}.{kind}-*"))


def files(root: Path) -> dict[str, bytes]:
    """Every visible file under ``root`` (relative path -> bytes)."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and not any(s.startswith(".") for s in p.relative_to(root).parts)}


# ----------------------------------------------------------------------------- simulate
@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """The uninterrupted simulation of the tiny preset's units 3 and 4 (seed 0)."""
    from engine_model.simulator.fleet import simulate

    out = tmp_path_factory.mktemp("sim") / "fleet"
    simulate("tiny", out=out, units=[3, 4], seed=0)
    return out


def _first_unit_in_partial(folder: Path, name: str):
    def ready():
        return any(datasets.written_units(t) for t in hidden(folder, name, "partial"))
    return ready


def test_sigkill_of_simulate_leaves_no_fleet_and_the_rerun_is_identical(tmp_path, simulated):
    """Killed after its first unit: no fleet under its name, the unit in the hidden partial
    fleet; the rerun (with --jobs 2) simulates the other unit only, in a worker process, and
    writes the uninterrupted fleet."""
    out = tmp_path / "fleet"
    p = start("simulate", "--preset", "tiny", "--units", "3,4", "--out", out, "--json")
    wait_for(p, _first_unit_in_partial(tmp_path, "fleet"), "the first simulated unit")
    code, _ = signal_and_wait(p, signal.SIGKILL)
    assert code == -signal.SIGKILL
    assert not out.exists()  # the fleet appears only complete
    (partial,) = hidden(tmp_path, "fleet", "partial")  # hidden: never read as data
    kept = datasets.written_units(partial)
    assert len(kept) == 1, kept  # killed between its two units
    # the rerun in a worker process (--jobs: one unit per task, the pool's path)
    r = hyprog("simulate", "--preset", "tiny", "--units", "3,4", "--out", out, "--json",
               "--jobs", "2")
    assert r.returncode == 0, r.stderr
    assert sorted(q.name for q in tmp_path.iterdir()) == ["fleet"]  # no partial, lock, temp
    assert files(out) == files(simulated)


def test_sigint_of_simulate_is_one_line_and_leaves_only_complete_units(tmp_path):
    out = tmp_path / "fleet"
    p = start("simulate", "--preset", "tiny", "--units", "3,4", "--out", out)
    wait_for(p, _first_unit_in_partial(tmp_path, "fleet"), "the first simulated unit")
    code, err = signal_and_wait(p, signal.SIGINT)
    assert code == 130, err
    assert err.strip() == "error: interrupted", err
    assert not out.exists() and not hidden(tmp_path, "fleet")  # no fleet, no temporary
    (partial,) = hidden(tmp_path, "fleet", "partial")  # what the next run continues
    assert [q.name for q in tmp_path.iterdir()] == [partial.name]  # the lock was released
    for unit in partial.iterdir():  # complete units only (and their info)
        assert unit.name == ".units" or (unit / datasets.PARQUET_PART).is_file(), unit


# ----------------------------------------------------------------------------- calibrate
@pytest.fixture(scope="module")
def cut(tmp_path_factory):
    """Unit 3 (first two cycles) and unit 4 (first five) of the tiny fleet, and their
    uninterrupted calibration (``hyprog calibrate --drift 0.01``'s settings)."""
    from calibration import CalibrationSetup
    from calibration.calibrate_fleet import calibrate_fleet

    df, meta = datasets.read_dataset(TINY, units=[3, 4])
    keep = ((df["unit"] == 3) & (df["cycle"] <= 2)) | ((df["unit"] == 4) & (df["cycle"] <= 5))
    root = tmp_path_factory.mktemp("cut")
    data = root / "fleet"
    datasets.write_parquet(df[keep].reset_index(drop=True), data, meta)
    ref = root / "features"
    calibrate_fleet(data, "ukf", CalibrationSetup(drift=float(DRIFT)),
                    out=ref, keep_results=False)
    return data, ref


def test_sigkill_of_calibrate_resumes_to_the_uninterrupted_files(tmp_path, cut):
    data, ref = cut
    out = tmp_path / "features"
    p = start("calibrate", data, "--drift", DRIFT, "--jobs", "2", "--out", out, "--json")
    wait_for(p, lambda: datasets.written_units(out), "the first calibrated unit")
    code, _ = signal_and_wait(p, signal.SIGKILL)
    assert code == -signal.SIGKILL
    written = datasets.written_units(out)
    assert written == [3], written  # the short unit was done, the long one was not
    visible = [q.name for q in out.iterdir() if not q.name.startswith(".")]
    assert visible == ["unit=3"], visible  # no half-written unit under its name
    assert files(out) == {k: v for k, v in files(ref).items() if k.startswith("unit=3/")}
    # the rerun: what `hyprog calibrate` calls, in this process (one command start less)
    from calibration import CalibrationSetup
    from calibration.calibrate_fleet import calibrate_fleet

    run = calibrate_fleet(data, "ukf", CalibrationSetup(drift=float(DRIFT)),
                          out=out, keep_results=False)
    assert run.skipped == [3] and sorted(run.units) == [4]  # unit 3 kept, unit 4 computed
    assert not [q for q in out.rglob(".*") if ".tmp-" in q.name]
    assert not lock_path(out).exists()  # the killed run's lock was taken over and released
    assert files(out) == files(ref)


def test_sigterm_of_calibrate_is_one_line(tmp_path, cut):
    data, _ = cut
    out = tmp_path / "features"
    p = start("calibrate", data, "--drift", DRIFT, "--out", out)
    wait_for(p, lambda: lock_path(out).exists(), "the output lock")
    code, err = signal_and_wait(p, signal.SIGTERM)
    assert code == 143, err
    assert err.strip() == "error: terminated", err
    assert not lock_path(out).exists()
    assert not [q for q in tmp_path.rglob(".*") if ".tmp-" in q.name]


@pytest.mark.parametrize("forget", [False, True])
def test_interrupt_caught_after_a_string_exec_still_exits_130_under_python_m(tmp_path, forget):
    """A Ctrl-C that lands inside a string ``exec`` (dataclasses, namedtuple) and is handled
    leaves CPython's 'unhandled KeyboardInterrupt' flag set, and ``python -m`` then dies by
    SIGINT (-2) instead of exiting 130; :func:`cli.common.forget_unhandled_interrupt`, called
    by the entry point before it exits, clears it. The unfixed case shows the test reaches
    the flag."""
    (tmp_path / "interrupted_module.py").write_text(
        "import sys\n"
        "from cli.common import forget_unhandled_interrupt\n"
        "try:\n"
        "    exec('raise KeyboardInterrupt', {})\n"
        "except KeyboardInterrupt:\n"
        "    pass\n"
        f"if {forget}:\n"
        "    forget_unhandled_interrupt()\n"
        "sys.exit(130)\n")
    env = {**ENV, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(REPO)])}
    r = subprocess.run([sys.executable, "-m", "interrupted_module"], env=env, cwd=tmp_path,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == (130 if forget else -signal.SIGINT), r.stderr


def _busy(seconds: float) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        pass


def test_an_interrupt_that_code_swallows_is_raised_again():
    """Code that clears the KeyboardInterrupt (as CasADi's SWIG overload checks do) does not
    lose the Ctrl-C: the block's timer raises it again, and nothing is left armed after."""
    from cli.common import TERMINATED, terminate_as_exit

    before = signal.getsignal(signal.SIGINT)  # SIG_IGN when pytest runs as a background job
    with pytest.raises(KeyboardInterrupt), terminate_as_exit():
        try:
            os.kill(os.getpid(), signal.SIGINT)
            _busy(1.0)
        except KeyboardInterrupt:
            pass  # swallowed
        _busy(2.0)
        raise AssertionError("the swallowed interrupt was not raised again")
    assert TERMINATED == [signal.SIGINT]
    assert signal.getsignal(signal.SIGINT) is before
    assert not [t for t in threading.enumerate() if t.name == "hyprog-signal-retry"]


def test_a_signal_while_the_block_is_left_is_recorded_and_raises_nothing(monkeypatch):
    """A Ctrl-C that lands in the block's own clean-up (here: inside the call that runs
    pending handlers) is recorded; nothing is raised, armed or left installed."""
    import time as time_module

    from cli.common import TERMINATED, terminate_as_exit

    real_sleep = time_module.sleep

    def sleep(seconds):
        os.kill(os.getpid(), signal.SIGINT)
        real_sleep(seconds)

    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    with terminate_as_exit():
        monkeypatch.setattr(time_module, "sleep", sleep)
    monkeypatch.setattr(time_module, "sleep", real_sleep)
    _busy(0.2)  # a late resend would raise here
    assert TERMINATED == [signal.SIGINT]
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


def test_an_interrupt_a_finalizer_drops_is_raised_again_and_not_printed(capsys):
    import weakref

    from cli.common import terminate_as_exit

    class Owner:
        pass

    def callback(_):
        os.kill(os.getpid(), signal.SIGINT)
        _busy(0.5)  # the KeyboardInterrupt is raised here, inside the finalizer

    with pytest.raises(KeyboardInterrupt), terminate_as_exit():
        owner = Owner()
        ref = weakref.ref(owner, callback)
        del owner  # the callback runs; Python drops its exception
        _busy(2.0)
        raise AssertionError(f"the dropped interrupt was not raised again ({ref})")
    assert "Exception ignored" not in capsys.readouterr().err


def test_a_signal_in_a_critical_section_is_raised_just_after_it():
    """A Ctrl-C while a lock is being taken or a folder swapped does not split the step: the
    section finishes, then the interrupt comes."""
    from cli.common import terminate_as_exit
    from engine_model.runtime.critical import critical_section

    finished = []
    with pytest.raises(KeyboardInterrupt), terminate_as_exit():
        with critical_section():
            os.kill(os.getpid(), signal.SIGINT)
            _busy(0.3)
            finished.append(True)
        _busy(2.0)
        raise AssertionError("the deferred interrupt was not raised after the section")
    assert finished == [True]


def test_a_critical_section_defers_any_handler_and_restores_it():
    """Without the CLI's handler too (Python's default KeyboardInterrupt): the section holds
    the signal back itself, puts the handler back, and nested sections defer to the outer."""
    from engine_model.runtime.critical import critical_section, in_critical_section

    # Python's own handler, whatever a test run before in this worker process left installed
    # (a worker may also start with SIGINT ignored): restored at the end
    outer = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        finished = []
        with pytest.raises(KeyboardInterrupt):
            with critical_section():
                with critical_section():
                    os.kill(os.getpid(), signal.SIGINT)
                    _busy(0.2)
                _busy(0.2)  # the inner section's end does not raise it
                finished.append(in_critical_section())
            raise AssertionError("the deferred interrupt was not raised after the section")
        assert finished == [True] and not in_critical_section()
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, outer)
