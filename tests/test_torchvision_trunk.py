"""models/resnet.py is torchvision's ResNet: same outputs and state dicts as the frozen hand-written trunk
(tests/legacy_resnet.py), SE gates in torchvision's blocks, ImageNet weights through the weights API."""

from __future__ import annotations

import copy
from urllib.error import URLError

import pytest
import torch
import torchvision
from torchvision.models import WeightsEnum

from models.fastpose import FastPose
from models.resnet import ResNet, load_imagenet
from models.tv_weights import WeightsUnavailable
from tests.legacy_resnet import LegacyResNet


def _randomize(model: torch.nn.Module, seed: int) -> torch.nn.Module:
    """Random values in every parameter and BatchNorm statistic (so that eval mode exercises them all)."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, tensor in model.state_dict().items():
            if tensor.is_floating_point():
                values = torch.rand(tensor.shape, generator=gen) + 0.5 if "running_var" in name else None
                values = torch.randn(tensor.shape, generator=gen) * 0.1 if values is None else values
                tensor.copy_(values)
    return model


@pytest.mark.parametrize("depth, se", [(18, False), (18, True), (50, False), (50, True)])
def test_same_weights_same_outputs_as_legacy(depth: int, se: bool) -> None:
    legacy = _randomize(LegacyResNet(depth, se=se), seed=depth + se).eval()
    trunk = ResNet(depth, se=se)
    trunk.load_state_dict(legacy.state_dict(), strict=True)
    x = torch.randn(2, 3, 64, 96, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        expected, got = legacy(x), trunk.eval()(x)
    assert got.shape == expected.shape == (2, trunk.out_channels, 2, 3)
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("depth", [18, 50])
def test_trunk_is_torchvision_resnet_without_classifier(depth: int) -> None:
    reference = torchvision.models.get_model(f"resnet{depth}", weights=None)
    expected = {k: v.shape for k, v in reference.state_dict().items() if not k.startswith("fc.")}
    assert {k: v.shape for k, v in ResNet(depth).state_dict().items()} == expected
    assert type(ResNet(depth).layer1[0]) is type(reference.layer1[0])
    assert not hasattr(ResNet(depth), "fc") and not hasattr(ResNet(depth), "avgpool")


def test_se_keys_and_positions_match_legacy() -> None:
    keys = set(ResNet(50, se=True).state_dict())
    assert keys == set(LegacyResNet(50, se=True).state_dict())
    assert "layer3.5.se.fc.0.weight" in keys and "layer4.2.se.fc.2.bias" in keys


def test_se_gate_changes_the_output_and_survives_deepcopy() -> None:
    torch.manual_seed(0)
    trunk = ResNet(18, se=True).eval()
    x = torch.randn(1, 3, 64, 64)
    with torch.no_grad():
        before = trunk(x)
        twin = copy.deepcopy(trunk)
        for block in (*twin.layer1, *twin.layer2, *twin.layer3, *twin.layer4):
            block.se.fc[2].bias.fill_(-30.0)  # gates ~ 0 in the copy only
        assert torch.equal(trunk(x), before)
        assert not torch.allclose(twin(x), before)


@pytest.mark.parametrize("depth, se", [(18, True), (50, False)])
def test_legacy_fastpose_state_dict_loads_strict_same_heatmaps(depth: int, se: bool) -> None:
    legacy = FastPose(depth=depth, se=se)
    legacy.preact = LegacyResNet(depth, se=se)  # FastPose as this repository built it before torchvision's trunk
    _randomize(legacy, seed=7).eval()
    state = legacy.state_dict()
    fresh = FastPose(depth=depth, se=se)
    fresh.load_state_dict(state, strict=True)
    x = torch.randn(2, 3, 64, 64, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        torch.testing.assert_close(fresh.eval()(x), legacy(x), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("exc", [URLError("no route"), OSError(101, "Network is unreachable")])
def test_imagenet_offline_is_one_line(monkeypatch: pytest.MonkeyPatch, exc: OSError) -> None:
    def offline(*args, **kwargs) -> dict:
        raise exc

    monkeypatch.setattr(WeightsEnum, "get_state_dict", offline)
    with pytest.raises(WeightsUnavailable) as info:
        FastPose(depth=50, pretrained="imagenet")
    message = str(info.value)
    assert "\n" not in message and info.value.__cause__ is None
    assert "model.pretrained" in message and "ResNet50_Weights.IMAGENET1K_V2" in message
    assert "resnet50-11ad3fa6.pth" in message and "cannot download" in message


def test_imagenet_loads_the_weights_api_state_dict(monkeypatch: pytest.MonkeyPatch) -> None:
    source = _randomize(torchvision.models.resnet18(weights=None), seed=3).state_dict()
    asked = []

    def cached(self: WeightsEnum, *args, **kwargs) -> dict:
        asked.append(self)
        return source

    monkeypatch.setattr(WeightsEnum, "get_state_dict", cached)
    trunk = ResNet(18, se=True)
    new = load_imagenet(trunk)
    assert asked == [torchvision.models.ResNet18_Weights.IMAGENET1K_V1]
    assert new and all(".se." in k for k in new)
    assert torch.equal(trunk.layer2[0].downsample[0].weight, source["layer2.0.downsample.0.weight"])
