"""Model versus the C-MAPSS FD002 early-life means at its six operating points.

Run by hand: ``python benchmarks/reference_points.py [CSV]``; prints the % error of every
channel the reference table shares with the model (:mod:`engine_model.analysis.reference`). Only the
SLS TRA 100 row is a design input (within 2 % by construction); the five other rows are
off-design predictions, and their residual is the starting point of the model-discrepancy work.
"""

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))
from engine_model.analysis import reference  # noqa: E402
from engine_model.runtime.shared_model import default_model  # noqa: E402


def main():
    path = sys.argv[1] if len(sys.argv) > 1 else reference.default_reference_path()
    records = reference.compare_reference(default_model(), reference.load_reference(path))
    err = reference.error_table(records)
    print("model error versus C-MAPSS [%]")
    print(err.to_string(float_format=lambda v: f"{v:+.2f}"))


if __name__ == "__main__":
    main()
