"""Channel names, groups and units, as in the paper and the N-CMAPSS files.

The N-CMAPSS h5 files store ``X_s`` as 14 channels and ``X_v`` as 14 channels; the paper moves
``T40`` and ``P30`` from ``X_v`` into its 16 measured channels. Both orders are defined here.
"""

W_NAMES = ("alt", "Mach", "TRA", "T2")
W_UNITS = {"alt": "ft", "Mach": "-", "TRA": "%", "T2": "degR"}

# the paper's 16 measured channels (Table: condition monitoring signals)
XS_NAMES = (
    "Wf", "Nf", "Nc", "T24", "T30", "T40", "T48", "T50",
    "P15", "P2", "P21", "P24", "Ps30", "P30", "P40", "P50",
)
# the paper's 11 virtual sensors
XV_NAMES = (
    "P45", "W21", "W22", "W25", "W31", "W32", "W48", "W50", "SmFan", "SmLPC", "SmHPC",
)
THETA_NAMES = (
    "fan_eff_mod", "fan_flow_mod", "LPC_eff_mod", "LPC_flow_mod", "HPC_eff_mod",
    "HPC_flow_mod", "HPT_eff_mod", "HPT_flow_mod", "LPT_eff_mod", "LPT_flow_mod",
)
PAPER_THETA = ("HPT_eff_mod", "LPT_eff_mod", "LPT_flow_mod")

# N-CMAPSS h5 layout
NCMAPSS_XS = (
    "T24", "T30", "T48", "T50", "P15", "P2", "P21", "P24", "Ps30", "P40", "P50", "Nf", "Nc", "Wf",
)
NCMAPSS_XV = (
    "T40", "P30", "P45", "W21", "W22", "W25", "W31", "W32", "W48", "W50",
    "SmFan", "SmLPC", "SmHPC", "phi",
)

# further model outputs beyond x_s and x_v
EXTRA_NAMES = ("phi", "Fn", "TSFC", "BPR", "epr", "NRf", "NRc", "PCNfR_dmd", "FAR")

UNITS = {
    "Wf": "lbm/s", "Nf": "rpm", "Nc": "rpm",
    "T24": "degR", "T30": "degR", "T40": "degR", "T48": "degR", "T50": "degR",
    "P15": "psia", "P2": "psia", "P21": "psia", "P24": "psia", "Ps30": "psia", "P30": "psia",
    "P40": "psia", "P50": "psia", "P45": "psia",
    "W21": "lbm/s", "W22": "lbm/s", "W25": "lbm/s", "W31": "lbm/s", "W32": "lbm/s",
    "W48": "lbm/s", "W50": "lbm/s",
    "SmFan": "%", "SmLPC": "%", "SmHPC": "%",
    "phi": "lbm/s/psia", "Fn": "lbf", "TSFC": "lbm/(lbf h)", "BPR": "-", "epr": "-",
    "NRf": "rpm", "NRc": "rpm", "PCNfR_dmd": "%", "FAR": "-",
    **W_UNITS,
    **{t: "-" for t in THETA_NAMES},
}

OUTPUT_NAMES = XS_NAMES + XV_NAMES + tuple(n for n in EXTRA_NAMES if n not in XV_NAMES)
