"""The runs of the paper's experiment: its parts, input sets, perturbations, and the plan of
training runs a configuration selects (the parts are described in :mod:`.experiment`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from engine_model.validation import InputError

PARTS = ("main", "small", "features", "calibration", "conformal")
MAIN_SETS = ("data-driven", "hybrid")
FEATURE_SETS = ("data-driven", "denoised", "virtual", "hybrid", "truth-theta")
PERFECT = "perfect"  # ablation III's perfect calibration (perfect_calibration)
PERFECT_SETS = ("denoised", "virtual", "hybrid")
PERTURBATIONS = {"snr20": ("noise", 20.0), "snr15": ("noise", 15.0),
                 "bias+0.5": ("bias", 0.5), "bias-0.5": ("bias", -0.5)}


@dataclass(frozen=True)
class Run:
    """One training run of the experiment."""

    part: str
    model: str
    inputs: str
    seed: int
    units: tuple[int, ...] | None = None
    perturbation: str | None = None
    conformal_units: tuple[int, ...] = ()

    def label(self) -> str:
        extra = [f"units {','.join(map(str, self.units))}" if self.units else "",
                 self.perturbation or "",
                 f"conformal {','.join(map(str, self.conformal_units))}"
                 if self.conformal_units else ""]
        tail = " ".join(e for e in extra if e)
        return f"{self.part}: {self.model} {self.inputs} seed {self.seed}" + \
            (f" ({tail})" if tail else "")


@dataclass(frozen=True)
class ExperimentConfig:
    seeds: tuple[int, ...] = (0, 1, 2, 3, 4)
    ablation_seeds: tuple[int, ...] | None = None
    parts: tuple[str, ...] = PARTS
    small_units: tuple[int, ...] = (16, 18, 20)
    epochs: int | None = None  # None: the paper's 60 (FNN) / 30 (CNN)
    device: str = "auto"
    alpha: float = 0.1
    baseline: bool = True
    #: draw the figures; False writes the tables only and removes the figures an earlier run
    #: drew into the same output (they would no longer match its tables)
    figures: bool = True

    def checked(self) -> ExperimentConfig:
        unknown = [p for p in self.parts if p not in PARTS]
        if unknown:
            raise InputError(f"unknown ablation(s) {', '.join(unknown)}; one of "
                             f"{', '.join(PARTS)}")
        if not self.seeds:
            raise InputError("experiment: no seeds")
        if not 0.0 < self.alpha < 1.0:
            raise InputError(f"experiment: --alpha must lie in (0, 1), got {self.alpha}")
        parts = tuple(dict.fromkeys(("main", *self.parts)))
        abl = self.ablation_seeds if self.ablation_seeds is not None else self.seeds[:3]
        return replace(self, parts=parts, ablation_seeds=tuple(abl))


def plan(cfg: ExperimentConfig, dev_units: Sequence[int]) -> list[Run]:
    """Every training run of the selected parts (module docstring)."""
    runs = [Run("main", m, s, seed) for m in ("fnn", "cnn") for s in MAIN_SETS
            for seed in cfg.seeds]
    abl = cfg.ablation_seeds
    if "small" in cfg.parts:
        runs += [Run("small", "cnn", s, seed, units=tuple(cfg.small_units))
                 for s in MAIN_SETS for seed in abl]
    if "features" in cfg.parts:
        runs += [Run("features", "cnn", s, seed) for s in FEATURE_SETS for seed in abl]
        runs += [Run("features", "cnn", s, seed, perturbation=PERFECT) for s in PERFECT_SETS
                 for seed in abl]
    if "calibration" in cfg.parts:
        runs += [Run("calibration", "cnn", "hybrid", seed, perturbation=p)
                 for p in PERTURBATIONS for seed in abl]
    if "conformal" in cfg.parts:
        if len(dev_units) < 2:
            raise InputError("conformal: needs at least two development units (one is held "
                             "out to calibrate)")
        runs += [Run("conformal", "cnn", s, seed,
                     conformal_units=(int(dev_units[seed % len(dev_units)]),))
                 for s in MAIN_SETS for seed in abl]
    return runs
