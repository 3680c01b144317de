"""RoNIN-ResNet (Herath et al., ICRA 2020): a 1-D residual network from IMU windows to 2-D velocity.

Written from the paper's description. The body is a 1-D ResNet: a stem convolution (kernel 7,
stride 2) with batch norm, ReLU and max pooling, then four groups of basic residual blocks whose
channels double and whose length halves from one group to the next. The head reduces the channels
with a 1x1 convolution, flattens the (short) time axis and regresses the velocity with two fully
connected layers. ``resnet18`` is the published size ([2, 2, 2, 2] blocks, 64 base channels);
``compact`` ([1, 1, 1, 1] blocks, 24 base channels) trains on two CPU cores.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import torch
from torch import nn

#: Named architectures: blocks per group, base channels, head sizes.
ARCHITECTURES: dict[str, dict] = {
    "resnet18": {"blocks": [2, 2, 2, 2], "base_channels": 64, "head_channels": 128, "head_hidden": 512},
    "compact": {"blocks": [1, 1, 1, 1], "base_channels": 24, "head_channels": 32, "head_hidden": 128},
}


@dataclass
class RoninConfig:
    """Everything needed to rebuild a model and feed it: stored as JSON beside the weights.

    Attributes
    ----------
    arch
        ``"compact"`` or ``"resnet18"`` (the defaults of the remaining size fields).
    blocks, base_channels, head_channels, head_hidden
        Network size.
    window, stride
        Samples per input window and between windows.
    rate_hz
        Input sampling rate.
    in_channels, out_dim
        6 (world-frame gyroscope and accelerometer) and 2 (horizontal velocity).
    feature_mean, feature_std
        Per-channel normalisation from the training data (applied inside the model).
    dropout
        Dropout of the head during training.
    output_scale
        Speed calibration applied to the output: 1 / the median distance ratio on the validation
        recordings (MSE regression on weak labels under-estimates distance); 1 during training.
    extra
        Provenance: training options, data, history, figures.
    """

    arch: str = "compact"
    blocks: list[int] = field(default_factory=lambda: list(ARCHITECTURES["compact"]["blocks"]))
    base_channels: int = ARCHITECTURES["compact"]["base_channels"]
    head_channels: int = ARCHITECTURES["compact"]["head_channels"]
    head_hidden: int = ARCHITECTURES["compact"]["head_hidden"]
    window: int = 200
    stride: int = 10
    rate_hz: float = 200.0
    in_channels: int = 6
    out_dim: int = 2
    feature_mean: list[float] = field(default_factory=lambda: [0.0] * 6)
    feature_std: list[float] = field(default_factory=lambda: [1.0] * 6)
    dropout: float = 0.5
    output_scale: float = 1.0
    extra: dict = field(default_factory=dict)

    @classmethod
    def for_arch(cls, arch: str, **kwargs) -> RoninConfig:
        """The config of a named architecture (see :data:`ARCHITECTURES`), with overrides."""
        if arch not in ARCHITECTURES:
            raise ValueError(f"unknown architecture {arch!r}; choose from {sorted(ARCHITECTURES)}")
        sizes = {k: (list(v) if isinstance(v, list) else v) for k, v in ARCHITECTURES[arch].items()}
        return cls(arch=arch, **{**sizes, **kwargs})

    def to_dict(self) -> dict:
        """Plain JSON-serialisable dict."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> RoninConfig:
        """Inverse of :meth:`to_dict` (unknown keys are rejected)."""
        return cls(**data)


class BasicBlock1D(nn.Module):
    """Two 3-tap convolutions with batch norm and an identity (or 1x1 projected) shortcut."""

    def __init__(self, in_channels: int, out_channels: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv1d(in_channels, out_channels, 3, stride=stride, padding=1, bias=False)
        self.bn1 = nn.BatchNorm1d(out_channels)
        self.conv2 = nn.Conv1d(out_channels, out_channels, 3, padding=1, bias=False)
        self.bn2 = nn.BatchNorm1d(out_channels)
        self.relu = nn.ReLU(inplace=True)
        self.shortcut: nn.Module = nn.Identity()
        if stride != 1 or in_channels != out_channels:
            self.shortcut = nn.Sequential(
                nn.Conv1d(in_channels, out_channels, 1, stride=stride, bias=False),
                nn.BatchNorm1d(out_channels),
            )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + self.shortcut(x))


def _length_after_body(window: int, n_groups: int) -> int:
    length = (window + 2 * 3 - 7) // 2 + 1  # stem conv, kernel 7, stride 2, padding 3
    length = (length + 2 * 1 - 3) // 2 + 1  # max pool, kernel 3, stride 2, padding 1
    for _ in range(n_groups - 1):  # every group after the first halves the length
        length = (length + 2 * 1 - 3) // 2 + 1
    return length


class RoninResNet(nn.Module):
    """RoNIN-ResNet: ``(B, 6, window)`` world-frame IMU windows to ``(B, 2)`` velocities (m/s).

    Parameters
    ----------
    config
        Sizes and the input normalisation (kept as buffers so a state_dict is self-contained).
    """

    def __init__(self, config: RoninConfig) -> None:
        super().__init__()
        self.config = config
        c = config.base_channels
        mean = torch.tensor(config.feature_mean, dtype=torch.float32).view(1, -1, 1)
        std = torch.tensor(config.feature_std, dtype=torch.float32).view(1, -1, 1)
        self.register_buffer("feature_mean", mean)
        self.register_buffer("feature_std", std)
        self.stem = nn.Sequential(
            nn.Conv1d(config.in_channels, c, 7, stride=2, padding=3, bias=False),
            nn.BatchNorm1d(c),
            nn.ReLU(inplace=True),
            nn.MaxPool1d(3, stride=2, padding=1),
        )
        groups = []
        in_ch = c
        for i, n_blocks in enumerate(config.blocks):
            out_ch = c * 2**i
            blocks = [BasicBlock1D(in_ch, out_ch, stride=1 if i == 0 else 2)]
            blocks += [BasicBlock1D(out_ch, out_ch) for _ in range(n_blocks - 1)]
            groups.append(nn.Sequential(*blocks))
            in_ch = out_ch
        self.body = nn.Sequential(*groups)
        length = _length_after_body(config.window, len(config.blocks))
        self.head = nn.Sequential(
            nn.Conv1d(in_ch, config.head_channels, 1, bias=False),
            nn.BatchNorm1d(config.head_channels),
            nn.ReLU(inplace=True),
            nn.Flatten(),
            nn.Linear(config.head_channels * length, config.head_hidden),
            nn.ReLU(inplace=True),
            nn.Dropout(config.dropout),
            nn.Linear(config.head_hidden, config.head_hidden),
            nn.ReLU(inplace=True),
            nn.Dropout(config.dropout),
            nn.Linear(config.head_hidden, config.out_dim),
        )
        for m in self.modules():
            if isinstance(m, nn.Conv1d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Velocity ``(B, 2)`` for windows ``(B, 6, window)`` in the model's world frame."""
        x = (x - self.feature_mean) / self.feature_std
        out = self.head(self.body(self.stem(x)))
        return out * self.config.output_scale if self.config.output_scale != 1.0 else out


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
