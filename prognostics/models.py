"""The paper's two prognostics networks (Sec. 4.3), built from its description.

FNN (time-independent): one time step ``x in R^n`` -> RUL, layers ``[n, 200, 200, 200, 50,
1]``, ReLU after every hidden layer, identity output. Parameters::

    (n + 1) 200 + 2 (201 x 200) + 201 x 50 + 51  = 94,701 for n = 20 (the paper's "95k"),
                                                   100,701 for n = 50

1-D CNN (time-dependent): a window ``(n channels, L = 50 time steps)`` ->
three ``Conv1d`` of kernel 10 with 10, 10 and 1 output channels, zero padding 'same' so
every map keeps length ``L``, ReLU after each; flatten (``L`` values); dense 50, ReLU; linear
output. An even kernel cannot pad symmetrically: output ``i`` sees inputs ``i - 4 .. i + 5``
(4 zeros left, 5 right, as PyTorch's ``padding='same'`` does). :class:`SameConv1d` gets it by
padding 5 on both sides inside the convolution and dropping the first output: the same
function as an explicit ``ZeroPad1d((4, 5))`` in front (tested), without a padded copy of
every batch and without the warning torch gives for ``padding='same'`` with an even kernel.
On CPU the convolutions are nearly all of a training step (``benchmarks/prognostics_speed.py``).
Parameters::

    (10 n + 1) 10 + (100 + 1) 10 + (100 + 1) + (L + 1) 50 + 51
        = 5,722 for n = 20, 8,722 for n = 50 (L = 50)

DCNN (Li, Ding & Sun, "Remaining useful life estimation in prognostics using deep
convolution neural networks", Reliab. Eng. Syst. Saf. 172, 2018, Sec. 3): a window ``(n, L)``
-> four convolutions over time of kernel 10 with 10 channels, a fifth of kernel 3 with one
channel ('same' padding, tanh after each); flatten (``L`` values); dropout 0.5; dense 100,
tanh; linear output. Li et al. train it on windows of 30 cycles (FD001/FD003) with targets
capped at 125 cycles; on FD001's test units it scored RMSE 12.61 (their Table 4). Parameters::

    (10 n + 1) 10 + 3 (100 + 1) 10 + (30 + 1) + (L + 1) 100 + 101
        = 7,672 for n = 14, L = 30

TCN (issue 30; the flight models ``tcn`` and ``trend``): a temporal convolutional network
over the last ``L`` flights of a flight table (:mod:`.flights`; Bai, Kolter & Koltun, "An
empirical evaluation of generic convolutional and recurrent networks for sequence modeling",
arXiv:1803.01271, 2018): residual blocks of one causal convolution each (kernel 3, dilations
1, 2, 4, 8: a receptive field of 31 flights), ReLU and dropout 0.2, a 1x1 convolution on the
skip path where the width changes; the last flight's features -> linear output. Causal: the
output at flight ``c`` reads flights ``c - 30 .. c`` only. Small on purpose (32 channels):
a fleet has hundreds of flights, not millions of samples. Parameters::

    (3 n + 1) 32 + (n + 1) 32 + 3 (3 x 32 + 1) 32 + 33 = 128 n + 9,409  (9,665 for n = 2)

The paper states "24k trainable parameters" for its CNN, which its own description cannot
give (the count above has no free choice left); we build the description and report the
count (:func:`parameter_count`).

Initialisation: Xavier/Glorot uniform weights (Glorot & Bengio 2010, the paper's choice),
zero biases, drawn from a ``torch.Generator`` seeded by the caller, so the global RNG state
does not matter.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from engine_model.validation import InputError

from .train_config import FLIGHT_MODELS, LIBRARY_MODELS, MODEL_KINDS

FNN_HIDDEN = (200, 200, 200, 50)
CNN_CHANNELS = (10, 10, 1)
CNN_KERNEL = 10
CNN_DENSE = 50


DCNN_CHANNELS = (10, 10, 10, 10)
DCNN_KERNEL = 10
DCNN_LAST_KERNEL = 3
DCNN_DENSE = 100
DCNN_DROPOUT = 0.5

TCN_CHANNELS = 32
TCN_KERNEL = 3
TCN_DILATIONS = (1, 2, 4, 8)
TCN_DROPOUT = 0.2


class FNN(nn.Module):
    """``[n, 200, 200, 200, 50, 1]`` ReLU network on one time step (module docstring)."""

    def __init__(self, n_inputs: int, hidden=FNN_HIDDEN):
        super().__init__()
        layers: list[nn.Module] = []
        width = n_inputs
        for h in hidden:
            layers += [nn.Linear(width, h), nn.ReLU()]
            width = h
        layers.append(nn.Linear(width, 1))
        self.net = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, n) -> (B,)
        return self.net(x).squeeze(-1)


class SameConv1d(nn.Conv1d):
    """``Conv1d`` whose output has the input's length: zero padding ``(k - 1) // 2`` on the
    left and ``k - 1 - (k - 1) // 2`` on the right (PyTorch's ``padding='same'``), done as the
    larger padding on both sides and the first ``offset`` outputs dropped.

    Computed as a channels-last 2-D convolution over a ``(B, c_in, 1, L)`` view: the same
    function and parameters as ``Conv1d`` (its ``weight`` is ``(c_out, c_in, k)``, so
    checkpoints do not change), but oneDNN's channels-last kernels take about 40 % less CPU
    per CNN training step than its 1-D channels-first ones at the paper's sizes (50 -> 10
    channels, kernel 10, L = 50, batch 1,024: 61-63 against 89-103 CPU ms per step, measured
    with ``benchmarks/prognostics_speed.py``'s network). A batch whose memory is already
    ``(B, L, c_in)`` (:meth:`prognostics.windows.Windows.batch`) is read without a copy."""

    def __init__(self, c_in: int, c_out: int, kernel: int):
        right = kernel - 1 - (kernel - 1) // 2
        super().__init__(c_in, c_out, kernel, padding=right)
        self.offset = right - (kernel - 1) // 2

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, c_in, L) -> (B, c_out, L)
        x4 = x.unsqueeze(2).contiguous(memory_format=torch.channels_last)
        y = F.conv2d(x4, self.weight.unsqueeze(2), self.bias, padding=(0, self.padding[0]))
        return y[:, :, 0, self.offset:self.offset + x.shape[-1]]


def conv_stack(n_inputs: int, channels, kernel: int, activation) -> list[nn.Module]:
    """'Same'-padded convolutions over time with ``channels`` outputs in turn, each followed by
    ``activation()``: the convolutional part of the CNN and the DCNN."""
    layers: list[nn.Module] = []
    c_in = n_inputs
    for c in channels:
        layers += [SameConv1d(c_in, c, kernel), activation()]
        c_in = c
    return layers


class CNN1D(nn.Module):
    """Three 1-D convolutions over time, dense 50, linear output (module docstring)."""

    def __init__(self, n_inputs: int, window: int, channels=CNN_CHANNELS,
                 kernel: int = CNN_KERNEL, dense: int = CNN_DENSE):
        super().__init__()
        layers = conv_stack(n_inputs, channels, kernel, nn.ReLU)
        layers += [nn.Flatten(), nn.Linear(channels[-1] * window, dense), nn.ReLU(),
                   nn.Linear(dense, 1)]
        self.net = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, n, L) -> (B,)
        return self.net(x).squeeze(-1)


class DCNN(nn.Module):
    """Li et al.'s deep CNN: five tanh convolutions, dropout, dense 100 (module docstring)."""

    def __init__(self, n_inputs: int, window: int):
        super().__init__()
        layers = conv_stack(n_inputs, DCNN_CHANNELS, DCNN_KERNEL, nn.Tanh)
        layers += [SameConv1d(DCNN_CHANNELS[-1], 1, DCNN_LAST_KERNEL), nn.Tanh(), nn.Flatten(),
                   nn.Dropout(DCNN_DROPOUT), nn.Linear(window, DCNN_DENSE), nn.Tanh(),
                   nn.Linear(DCNN_DENSE, 1)]
        self.net = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, n, L) -> (B,)
        return self.net(x).squeeze(-1)


class CausalBlock(nn.Module):
    """One residual block of the TCN: ``x + dropout(relu(conv_d(x)))`` with the convolution
    padded on the left only (output ``i`` reads inputs ``i - (k - 1) d .. i``) and a 1x1
    convolution on the skip path when the width changes."""

    def __init__(self, c_in: int, c_out: int, kernel: int, dilation: int, dropout: float):
        super().__init__()
        self.pad = (kernel - 1) * dilation
        self.conv = nn.Conv1d(c_in, c_out, kernel, dilation=dilation)
        self.skip = nn.Conv1d(c_in, c_out, 1) if c_in != c_out else nn.Identity()
        self.drop = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, c_in, L) -> (B, c_out, L)
        y = self.drop(torch.relu(self.conv(F.pad(x, (self.pad, 0)))))
        return self.skip(x) + y


class TCN(nn.Module):
    """Temporal CNN over flights (module docstring): causal residual blocks, last step."""

    def __init__(self, n_inputs: int, channels: int = TCN_CHANNELS, kernel: int = TCN_KERNEL,
                 dilations=TCN_DILATIONS, dropout: float = TCN_DROPOUT):
        super().__init__()
        blocks, c_in = [], n_inputs
        for d in dilations:
            blocks.append(CausalBlock(c_in, channels, kernel, d, dropout))
            c_in = channels
        self.blocks = nn.Sequential(*blocks)
        self.out = nn.Linear(channels, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, n, L) -> (B,)
        return self.out(self.blocks(x)[:, :, -1]).squeeze(-1)


def build_model(kind: str, n_inputs: int, window: int, seed: int | None = None) -> nn.Module:
    """A network of ``kind`` (``fnn``, ``cnn``, ``dcnn``, or the flight models ``tcn`` and
    ``trend``, both a :class:`TCN`; ``similarity`` has no network); Xavier-initialised from
    ``seed`` when given (otherwise left for :meth:`load_state_dict`)."""
    if kind not in MODEL_KINDS:
        raise InputError(f"unknown model {kind!r}; one of {', '.join(MODEL_KINDS)}")
    if kind in LIBRARY_MODELS:
        raise InputError(f"the {kind} model has no network (prognostics.similarity)")
    if n_inputs < 1:
        raise InputError("a model needs at least one input column")
    if kind == "fnn":
        if window != 1:
            raise InputError(f"the FNN takes one time step (the paper's); window {window} "
                             "applies to the CNN only")
        model: nn.Module = FNN(n_inputs)
    else:
        if window < 1:
            raise InputError(f"window must be >= 1, got {window}")
        if kind in FLIGHT_MODELS:
            model = TCN(n_inputs)
        else:
            model = CNN1D(n_inputs, window) if kind == "cnn" else DCNN(n_inputs, window)
    if seed is not None:
        xavier_init(model, seed)
    return model


def xavier_init(model: nn.Module, seed: int) -> None:
    """Glorot-uniform weights and zero biases of every Linear/Conv1d layer, from ``seed``."""
    g = torch.Generator().manual_seed(int(seed))
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, (nn.Linear, nn.Conv1d)):
                nn.init.xavier_uniform_(m.weight, generator=g)
                nn.init.zeros_(m.bias)


def parameter_count(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
