"""ResNet trunk (18/34/50/101/152): torchvision's ResNet without avgpool and fc, optional squeeze-excitation gates."""

from __future__ import annotations

import functools
import logging
from pathlib import Path

import torchvision
from torch import Tensor, nn
from torchvision.models.resnet import BasicBlock, Bottleneck

from models.tv_weights import check_state_fits, download_state_dict, read_state_dict

log = logging.getLogger(__name__)

DEPTHS = (18, 34, 50, 101, 152)
SE_REDUCTION = 16


class SELayer(nn.Module):
    """Squeeze-excitation: channel gates from global average pooling; names ``fc.0``, ``fc.2``."""

    def __init__(self, channels: int, reduction: int = SE_REDUCTION) -> None:
        super().__init__()
        hidden = max(channels // reduction, 1)
        self.avg_pool = nn.AdaptiveAvgPool2d(1)
        self.fc = nn.Sequential(
            nn.Linear(channels, hidden), nn.ReLU(inplace=True), nn.Linear(hidden, channels), nn.Sigmoid()
        )

    def forward(self, x: Tensor) -> Tensor:
        """(B, C, H, W) -> (B, C, H, W), each channel scaled by a gate in (0, 1)."""
        return x * self.fc(self.avg_pool(x).flatten(1))[:, :, None, None]


def _gate_output(se: SELayer, module: nn.Module, inputs: tuple, output: Tensor) -> Tensor:
    """Forward hook of a block's last BatchNorm: its output through the block's SE gate."""
    return se(output)


def add_squeeze_excitation(block: BasicBlock | Bottleneck) -> None:
    """Give a torchvision block an SE gate (``block.se``) on the output of its last BatchNorm."""
    last_bn = block.bn3 if isinstance(block, Bottleneck) else block.bn2
    block.se = SELayer(last_bn.num_features)
    # a partial (not a closure) so that copy.deepcopy of the trunk gates with the copied SE module
    last_bn.register_forward_hook(functools.partial(_gate_output, block.se))


class ResNet(nn.Module):
    """ResNet trunk without the classifier; ``out_channels`` is the channel count of its output."""

    def __init__(self, depth: int = 50, se: bool = False) -> None:
        super().__init__()
        if depth not in DEPTHS:
            raise ValueError(f"ResNet depth must be one of {list(DEPTHS)}, got {depth}")
        net = torchvision.models.get_model(f"resnet{depth}", weights=None)
        self.depth, self.se = depth, se
        self.conv1, self.bn1, self.relu, self.maxpool = net.conv1, net.bn1, net.relu, net.maxpool
        self.layer1, self.layer2, self.layer3, self.layer4 = net.layer1, net.layer2, net.layer3, net.layer4
        self.out_channels = net.fc.in_features
        if se:
            for layer in (self.layer1, self.layer2, self.layer3, self.layer4):
                for block in layer:
                    add_squeeze_excitation(block)

    def forward(self, x: Tensor) -> Tensor:
        """(B, 3, H, W) -> (B, out_channels, H/32, W/32)."""
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        return self.layer4(self.layer3(self.layer2(self.layer1(x))))


def load_trunk_state(model: ResNet, state: dict[str, Tensor], source: str) -> list[str]:
    """Load a torchvision ImageNet state dict into model -> the SE keys left new; ValueError naming source."""
    state = {k: v for k, v in state.items() if not k.startswith("fc.")}
    own = model.state_dict()
    check_state_fits(own, state, source, f"a ResNet-{model.depth} trunk", may_miss=lambda k: ".se." in k)
    model.load_state_dict(state, strict=False)
    new_keys = sorted(k for k in own if k not in state)
    if new_keys:
        log.info("%s: %d squeeze-excitation keys newly initialised", source, len(new_keys))
    return new_keys


def load_pretrained(model: ResNet, path: str | Path) -> list[str]:
    """Load a torchvision ImageNet state dict file into ``model`` (checks of ``load_trunk_state``)."""
    return load_trunk_state(model, read_state_dict(path), str(path))


def load_imagenet(model: ResNet, key: str = "model.pretrained") -> list[str]:
    """Load torchvision's default ImageNet weights of the trunk's depth; offline, WeightsUnavailable naming key."""
    weights = torchvision.models.get_model_weights(f"resnet{model.depth}").DEFAULT
    return load_trunk_state(model, download_state_dict(weights, key), str(weights))
