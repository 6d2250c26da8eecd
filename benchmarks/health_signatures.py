"""Health-signature table: every health parameter at -2 %, seven gas-path channels, at sea-level
take-off, climb and cruise.

Run by hand: ``python benchmarks/health_signatures.py``. Prints a markdown table of the change
of T24, T30, T48, T50 [degR], P30 [psia], Nc [rpm] and Wf [pph] when one health parameter
(``engine_model.THETA_NAMES``) is lowered by 0.02 at fixed TRA, and marks with ``!`` a change
whose sign differs between the three points while exceeding the channel's noise sigma
(``engine_model.simulator.sensor_noise``) at both. ``tests/test_physics_maps.py`` asserts the same
table's sign consistency.
"""

import argparse
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))


def main(argv=None):
    argparse.ArgumentParser(description=__doc__,
                            formatter_class=argparse.RawDescriptionHelpFormatter
                            ).parse_args(argv)
    import numpy as np

    from engine_model.analysis.signatures import (
        SIGNATURE_CHANNELS,
        SIGNATURE_POINTS,
        signature_table,
    )
    from engine_model.runtime.shared_model import default_model

    tab, sigma, flips = signature_table(default_model())
    pts = list(SIGNATURE_POINTS)
    head = "| theta -2 % | " + " | ".join(f"{c} {p}" for c in SIGNATURE_CHANNELS for p in pts)
    print("points: " + "; ".join(f"{k} = alt {v[0]:.0f} ft, Mach {v[1]}, TRA {v[2]}"
                                 for k, v in SIGNATURE_POINTS.items()))
    print("units: degR (T), psia (P30), rpm (Nc), pph (Wf); ! = sign flip beyond noise")
    print(head + " |")
    print("|" + "---|" * (1 + len(SIGNATURE_CHANNELS) * len(pts)))
    for name in tab:
        cells = []
        for c in SIGNATURE_CHANNELS:
            for p in pts:
                v = tab[name][c][p]
                mark = "!" if (name, c) in flips else ""
                cells.append(f"{v:+.3g}{mark}")
        print(f"| {name} | " + " | ".join(cells) + " |")
    print("noise sigma: " + ", ".join(
        f"{c} {np.round([sigma[c][p] for p in pts], 3).tolist()}" for c in SIGNATURE_CHANNELS))
    print(f"sign flips beyond noise: {sorted(flips) if flips else 'none'}")


if __name__ == "__main__":
    main()
