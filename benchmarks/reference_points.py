"""Model versus the C-MAPSS FD002 early-life means at its six operating points.

Run by hand: ``python benchmarks/reference_points.py [CSV]``; prints the % error of every
channel the reference table shares with the model. Only the SLS TRA 100 row is a design
input (within 2 % by construction); the five other rows are off-design predictions, and
their residual is the starting point of the model-discrepancy work.
"""

import os
import sys

import numpy as np
import pandas as pd

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))
from engine_model import EngineModel  # noqa: E402

CHANNELS = ("T24", "T30", "T50", "P2", "P15", "P30", "Nf", "Nc", "epr", "NRf", "NRc", "BPR",
            "W31", "W32")


def main():
    path = sys.argv[1] if len(sys.argv) > 1 else os.path.join(
        HERE, "..", "data_samples", "cmapss-fd002-operating-points.csv")
    ref = pd.read_csv(path)
    m = EngineModel()
    w = np.column_stack([ref.alt_kft * 1000.0, ref.Mach, ref.TRA, ref.T2])
    out = m.evaluate(w)
    err = pd.DataFrame({c: 100.0 * (out[c].to_numpy() / ref[c].to_numpy() - 1.0)
                        for c in CHANNELS})
    err.insert(0, "point", [f"{a:g} kft M{mm:g} TRA{t:g}" for a, mm, t in
                            zip(ref.alt_kft, ref.Mach, ref.TRA, strict=True)])
    print("model error versus C-MAPSS [%]")
    print(err.to_string(index=False, float_format=lambda v: f"{v:+.2f}"))


if __name__ == "__main__":
    main()
