"""Speed of the prognostics training and the memory of window building (issue 13's benchmark).

Run by hand: ``python benchmarks/prognostics_speed.py [--units 6 --cycles 75 --samples 1180]
[--threads 1,2]``. Prints a table; ``benchmarks/results/prognostics_speed.md`` holds the runs.
On a machine other jobs share, run it (and train) with ``OMP_WAIT_POLICY=PASSIVE``: OpenMP's
spinning threads otherwise cost 2-3x in wall time (measured there).

What it measures, on a development set the size of ``ds02``'s at 0.1 Hz (the paper: 0.53 M
samples of 6 units; here 6 units x 75 cycles x 1,180 samples = 0.53 M rows) with the hybrid
input set (50 columns) and the paper's CNN set-up (window 50, stride 1, batch 1024):

- **window building**: :func:`prognostics.training.prepare` (input resolution, roles with 10 %
  validation flights, min-max scaling, windows of every role), its wall time and the peak of
  the memory it allocates (``tracemalloc``: numpy reports its buffers to it; ``torch.from_numpy``
  allocates nothing), set beside the size of the scaled rows and the size that one copy per
  window would take (``windows x 50 x 50 x 4 B``);
- **one CNN epoch**: one pass of AMSGrad over every training window in mini-batches of 1024
  plus the validation pass, with ``torch.set_num_threads(threads)`` for each ``--threads``
  value (default 2: the 2 cores of the target machine), wall seconds, CPU seconds of the
  process (``time.process_time``, all threads) and training windows per training second (the
  epoch's own time as the training records it, ``history[0]["seconds"]``: the train and
  validation passes, without the set-up that the wall time includes). Target (issue 13):
  <= 30 s. On a CPU that other jobs share, wall time overstates the cost (and two
  OpenMP threads that must meet at every barrier suffer most); the CPU seconds are the cost
  an idle machine pays, spread over its threads.

The table is synthetic: random values of the right shape and names. Speed does not depend on
the values (no data-dependent branch in scaling, windowing, convolution or the optimiser), so
this is the cost of the real data set; the loss printed means nothing. Timings depend on what
else runs on the machine: the result file notes the load.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import time
import tracemalloc

import numpy as np
import pandas as pd

# (torch and the project are imported where they are used: ``--help`` answers at once)

THETA_HAT = ("HPT_eff_mod_hat", "LPT_eff_mod_hat", "LPT_flow_mod_hat")  # ds02's calibration


def synthetic_table(units: int, cycles: int, samples: int, seed: int = 0) -> pd.DataFrame:
    """``units`` x ``cycles`` x ``samples`` rows with the 50 hybrid input columns, random."""
    from engine_model.channels import W_NAMES, XS_NAMES, XV_NAMES

    rng = np.random.default_rng(seed)
    n_unit = cycles * samples
    n = units * n_unit
    cols = [*W_NAMES, *XS_NAMES, *(c + "_hat" for c in XS_NAMES),
            *(c + "_hat" for c in XV_NAMES), *THETA_HAT]
    data = {"unit": np.repeat(np.arange(1, units + 1), n_unit),
            "cycle": np.tile(np.repeat(np.arange(1, cycles + 1), samples), units),
            "t": np.tile(10.0 * np.arange(samples, dtype=float), units * cycles)}
    data["RUL"] = (cycles - data["cycle"]).astype(float)
    values = rng.standard_normal((n, len(cols)), dtype=np.float32).astype(np.float64)
    df = pd.DataFrame(values, columns=cols)
    for k in ("unit", "cycle", "t", "RUL"):
        df.insert(0, k, data[k])
    return df


#: the 1-minute load average before the work above which the result says that other jobs
#: shared the CPU
BUSY_LOAD = 0.5


def load_average() -> tuple[float, float, float] | None:
    """``os.getloadavg()``, None where the system has none."""
    try:
        return os.getloadavg()
    except OSError:
        return None


def fmt_load(loads) -> str:
    return "n/a" if loads is None else " / ".join(f"{v:.2f}" for v in loads)


def rss_mib() -> float:
    """Peak resident set size of this process so far [MiB] (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--units", type=int, default=6)
    ap.add_argument("--cycles", type=int, default=75)
    ap.add_argument("--samples", type=int, default=1180, help="samples per cycle")
    ap.add_argument("--threads", default="2", help="torch thread counts, e.g. 1,2")
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--window", type=int, default=50)
    a = ap.parse_args()
    import torch

    from prognostics.models import build_model, parameter_count
    from prognostics.splits import TRAIN, VALIDATION
    from prognostics.train_config import TrainConfig
    from prognostics.training import prepare, resolve_device, train_member

    start_load = load_average()
    threads = [int(t) for t in a.threads.split(",")]
    torch.set_num_threads(threads[0])

    df = synthetic_table(a.units, a.cycles, a.samples)
    meta = {"dev_units": list(range(1, a.units + 1)), "test_units": []}
    cfg = TrainConfig(model="cnn", inputs="hybrid", window=a.window, epochs=1,
                      batch_size=a.batch, device="cpu", seed=0)
    rss_table = rss_mib()

    tracemalloc.start()
    t0 = time.perf_counter()
    prep = prepare(df, meta, cfg)
    t_prep = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss_prep = rss_mib()

    k = len(prep.columns)
    n_rows = len(prep.frame)
    n_train = len(prep.windows[TRAIN])
    n_val = len(prep.windows[VALIDATION]) if VALIDATION in prep.windows else 0
    n_win = n_train + n_val
    rows_bytes = n_rows * k * 4
    copy_bytes = n_win * a.window * k * 4
    shares = bool(np.shares_memory(prep.windows[TRAIN].base.numpy(),
                                   prep.windows[VALIDATION].base.numpy())) if n_val else None

    device = resolve_device("cpu")
    epochs = []
    for n_threads in threads:
        torch.set_num_threads(n_threads)
        t0, c0 = time.perf_counter(), time.process_time()
        member = train_member(prep, seed=0, device=device)
        epochs.append((n_threads, time.perf_counter() - t0, time.process_time() - c0,
                       member.history[0]["seconds"]))
    params = parameter_count(build_model("cnn", k, a.window))

    mib = 2.0 ** 20
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, torch {torch.__version__}")
    end_load = load_average()
    # before the work the load is other jobs' (and the last minute's): above BUSY_LOAD they
    # shared the CPU; at the end it holds this benchmark's own threads too
    shared = start_load is not None and start_load[0] > BUSY_LOAD
    print("load average (1/5/15 min) at the start: " + fmt_load(start_load)
          + "; at the end: " + fmt_load(end_load)
          + (" (other jobs share the CPU: timings are upper bounds of an idle machine's)"
             if shared else ""))
    print(f"data: synthetic, {a.units} units x {a.cycles} cycles x {a.samples} samples = "
          f"{n_rows:,} rows x {k} input columns (hybrid set); values random (speed does not "
          "depend on them)")
    print(f"CNN: window {a.window}, {params:,} parameters, batch {a.batch}, AMSGrad lr 1e-3")
    print()
    print(f"{'quantity':<52}{'value':>18}")
    table = [
        ("training windows", f"{n_train:,}"),
        ("validation windows (10 % of the flights)", f"{n_val:,}"),
        ("window building + scaling (prepare) [s]", f"{t_prep:.2f}"),
        ("peak traced allocation in prepare [MiB]", f"{peak / mib:,.1f}"),
        ("  scaled rows, one float32 copy [MiB]", f"{rows_bytes / mib:,.1f}"),
        ("  one copy per window would be [MiB]", f"{copy_bytes / mib:,.1f}"),
        ("  train and validation windows share one base", str(shares)),
        ("peak RSS before / after prepare [MiB]", f"{rss_table:,.0f} / {rss_prep:,.0f}"),
    ]
    for n_threads, wall, cpu, recorded in epochs:
        table += [
            (f"one CNN epoch, {n_threads} torch thread(s): wall [s]", f"{wall:.1f}"),
            ("  CPU seconds of the process (all threads)", f"{cpu:.1f}"),
            ("  training windows per training second", f"{n_train / recorded:,.0f}"),
            ("  target one epoch <= 30 s (wall)", "met" if wall <= 30.0 else "NOT met"),
        ]
    table.append(("peak RSS after the epochs [MiB]", f"{rss_mib():,.0f}"))
    for name, value in table:
        print(f"{name:<52}{value:>18}")


if __name__ == "__main__":
    main()
