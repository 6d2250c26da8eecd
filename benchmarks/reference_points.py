"""Model versus the C-MAPSS FD002 early-life means at its six operating points.

Run by hand: ``python benchmarks/reference_points.py [CSV]``; prints the % error of every
channel the reference table shares with the model (:mod:`engine_model.analysis.reference`;
CSV defaults to its packaged reference table). Only the SLS TRA 100 row is a design input
(within 2 % by construction); the five other rows are off-design predictions, and their
residual is the starting point of the model-discrepancy work.
"""

import argparse
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("csv", nargs="?", default=None,
                    help="the reference table (default: the packaged C-MAPSS FD002 one)")
    a = ap.parse_args(argv)
    from engine_model.analysis import reference
    from engine_model.runtime.shared_model import default_model

    path = a.csv if a.csv is not None else reference.default_reference_path()
    records = reference.compare_reference(default_model(), reference.load_reference(path))
    err = reference.error_table(records)
    print("model error versus C-MAPSS [%]")
    print(err.to_string(float_format=lambda v: f"{v:+.2f}"))


if __name__ == "__main__":
    main()
