"""What defines a training run: :class:`TrainConfig` (stored with every model) and the
networks' defaults, without importing torch (a configuration is read, checked and written
without loading the training machinery).

The paper's settings (Sec. 4.3-4.4): the FNN sees one time step and trains at most 60
epochs, the CNN a window of 50 samples and at most 30 epochs; mini-batches of 1024, learning
rate 1e-3, early-stopping patience 5.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

from engine_model.validation import InputError

MODEL_KINDS = ("fnn", "cnn")
DEFAULT_EPOCHS = {"fnn": 60, "cnn": 30}
DEFAULT_WINDOW = {"fnn": 1, "cnn": 50}


@dataclass(frozen=True)
class TrainConfig:
    """Everything that defines a training run (stored with the model)."""

    model: str = "cnn"
    inputs: str = "hybrid"
    window: int | None = None  # None: 50 for the CNN, 1 (one time step) for the FNN
    stride: int = 1
    max_rul: float | None = None
    seed: int = 0
    epochs: int | None = None  # None: 60 (FNN) / 30 (CNN)
    batch_size: int = 1024
    lr: float = 1e-3
    patience: int = 5
    val_fraction: float = 0.1
    validation: str = "flights"
    val_units: tuple[int, ...] | None = None
    units: tuple[int, ...] | None = None  # development units (default: the metadata's)
    test_units: tuple[int, ...] | None = None  # default: the metadata's
    conformal_units: tuple[int, ...] = ()
    alpha: float = 0.1
    device: str = "auto"

    def resolved(self) -> TrainConfig:
        """Defaults filled in and values checked."""
        if self.model not in MODEL_KINDS:
            raise InputError(f"unknown model {self.model!r}; one of {', '.join(MODEL_KINDS)}")
        c = replace(self,
                    window=DEFAULT_WINDOW[self.model] if self.window is None else self.window,
                    epochs=DEFAULT_EPOCHS[self.model] if self.epochs is None else self.epochs)
        for name in ("window", "stride", "epochs", "batch_size"):
            if int(getattr(c, name)) < 1:
                raise InputError(f"{name} must be >= 1, got {getattr(c, name)}")
        if c.patience < 1:
            raise InputError(f"patience must be >= 1, got {c.patience}")
        if c.max_rul is not None and c.max_rul <= 0:
            raise InputError(f"max_rul must be positive, got {c.max_rul}")
        if not c.lr > 0:
            raise InputError(f"learning rate must be positive, got {c.lr}")
        return c

    def to_dict(self) -> dict:
        d = asdict(self)
        for k in ("val_units", "units", "test_units", "conformal_units"):
            if d[k] is not None:
                d[k] = [int(u) for u in d[k]]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        known = {f for f in cls.__dataclass_fields__}
        unknown = sorted(set(d) - known)
        if unknown:
            raise InputError(f"training config: unknown key(s) {', '.join(unknown)}")
        kw = dict(d)
        for k in ("val_units", "units", "test_units", "conformal_units"):
            if kw.get(k) is not None:
                kw[k] = tuple(int(u) for u in kw[k])
        return cls(**kw)
