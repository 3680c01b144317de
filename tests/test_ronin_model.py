"""RoNIN-ResNet: shapes, sizes, yaw augmentation, normalisation, weights round trip."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from curbside import settings
from curbside.errors import CurbsideInputError
from curbside.localize.paths import config_path_for
from curbside.localize.ronin.infer import load_model
from curbside.localize.ronin.model import BasicBlock1D, RoninConfig, RoninResNet, count_parameters
from curbside.localize.ronin.train import normalisation_stats, rotate_yaw, save_weights


@pytest.mark.parametrize("arch", ["compact", "resnet18"])
def test_output_shape_is_batch_by_two(arch):
    model = RoninResNet(RoninConfig.for_arch(arch)).eval()
    with torch.no_grad():
        assert model(torch.randn(5, 6, 200)).shape == (5, 2)


def test_resnet18_has_the_published_body():
    model = RoninResNet(RoninConfig.for_arch("resnet18"))
    blocks = [m for m in model.body.modules() if isinstance(m, BasicBlock1D)]
    assert len(blocks) == 8
    assert [g[0].conv1.out_channels for g in model.body] == [64, 128, 256, 512]
    assert count_parameters(model) > 10 * count_parameters(RoninResNet(RoninConfig.for_arch("compact")))


def test_other_window_lengths_build():
    model = RoninResNet(RoninConfig.for_arch("compact", window=50)).eval()
    with torch.no_grad():
        assert model(torch.randn(2, 6, 50)).shape == (2, 2)


def test_unknown_architecture_is_rejected():
    with pytest.raises(ValueError, match="unknown architecture"):
        RoninConfig.for_arch("resnet50")


def test_yaw_rotation_turns_inputs_and_targets_together():
    x = torch.zeros(1, 6, 4)
    x[0, 0] = 1.0  # gyro x
    x[0, 3] = 2.0  # acc x
    x[0, 5] = 9.8  # acc z untouched
    y = torch.tensor([[1.0, 0.0]])
    xr, yr = rotate_yaw(x, y, torch.tensor([math.pi / 2]))
    assert torch.allclose(yr, torch.tensor([[0.0, 1.0]]), atol=1e-6)
    assert torch.allclose(xr[0, :, 0], torch.tensor([0.0, 1.0, 0.0, 0.0, 2.0, 9.8]), atol=1e-6)
    back, yb = rotate_yaw(xr, yr, torch.tensor([-math.pi / 2]))
    assert torch.allclose(back, x, atol=1e-6) and torch.allclose(yb, y, atol=1e-6)


def test_normalisation_commutes_with_yaw_rotation():
    rng = np.random.default_rng(0)
    feats = rng.normal([0.1, -0.2, 0.0, 0.5, 0.3, 9.8], [1, 2, 0.5, 1, 3, 1], (5000, 6)).astype(np.float32)
    mean, std = normalisation_stats(feats)
    m = torch.tensor(mean).view(1, 6, 1)
    s = torch.tensor(std).view(1, 6, 1)
    x = torch.from_numpy(feats[:64].T.copy()).unsqueeze(0)
    angle = torch.tensor([0.7])
    a, _ = rotate_yaw((x - m) / s, torch.zeros(1, 2), angle)
    b = (rotate_yaw(x, torch.zeros(1, 2), angle)[0] - m) / s
    assert torch.allclose(a, b, atol=1e-5)
    assert std[0] == std[1] and std[3] == std[4] and mean[0] == mean[1] == 0.0


def test_weights_round_trip_through_plain_state_dict(tmp_path):
    torch.manual_seed(0)
    model = RoninResNet(RoninConfig.for_arch("compact", feature_mean=[0, 0, 0.1, 0, 0, 9.8])).eval()
    path = save_weights(model, tmp_path / "m.pt")
    state = torch.load(path, weights_only=True)
    assert all(isinstance(v, torch.Tensor) for v in state.values())
    loaded = load_model(path)
    x = torch.randn(3, 6, 200)
    with torch.no_grad():
        assert torch.allclose(model(x), loaded(x))
    assert json.loads(config_path_for(path).read_text())["arch"] == "compact"


def test_output_scale_multiplies_velocity():
    torch.manual_seed(0)
    model = RoninResNet(RoninConfig.for_arch("compact")).eval()
    x = torch.randn(2, 6, 200)
    with torch.no_grad():
        base = model(x)
        model.config.output_scale = 1.25
        assert torch.allclose(model(x), 1.25 * base)


def test_missing_or_mismatched_weights_are_input_errors(tmp_path):
    with pytest.raises(CurbsideInputError, match="no such"):
        load_model(tmp_path / "absent.pt")
    model = RoninResNet(RoninConfig.for_arch("compact"))
    path = save_weights(model, tmp_path / "m.pt")
    cfg = json.loads(config_path_for(path).read_text())
    cfg["base_channels"] = 8
    config_path_for(path).write_text(json.dumps(cfg))
    with pytest.raises(CurbsideInputError, match="state_dict"):
        load_model(path)
    config_path_for(path).write_text("{not json")
    with pytest.raises(CurbsideInputError, match="config"):
        load_model(path)


def test_bundled_weights_load_and_are_small():
    assert settings.ronin_default_weights.is_file()
    assert settings.ronin_default_weights.stat().st_size < 5_000_000
    model = load_model()
    assert model.config.window == 200 and model.config.rate_hz == 200.0 and model.config.stride == 10
    assert not model.training
