"""FastPose heatmap network (AlphaPose's SPPE): ResNet trunk, PixelShuffle, two DUC blocks, 3x3 head; stride 4."""

from __future__ import annotations

from pathlib import Path

from torch import Tensor, nn

from data.keypoints import NUM_JOINTS
from models.resnet import ResNet, load_imagenet, load_pretrained

IMAGENET = "imagenet"  # model.pretrained value: torchvision's default ImageNet weights of the depth


class DUC(nn.Module):
    """Dense upsampling convolution: 3x3 conv (no bias), BatchNorm, ReLU, PixelShuffle."""

    def __init__(self, cin: int, cout: int, upscale: int = 2) -> None:
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, kernel_size=3, padding=1, bias=False)
        self.bn = nn.BatchNorm2d(cout)
        self.relu = nn.ReLU(inplace=True)
        self.pixel_shuffle = nn.PixelShuffle(upscale)

    def forward(self, x: Tensor) -> Tensor:
        """(B, cin, H, W) -> (B, cout / upscale^2, upscale * H, upscale * W)."""
        return self.pixel_shuffle(self.relu(self.bn(self.conv(x))))


class FastPose(nn.Module):
    """Single-person pose network: (B, 3, H, W) crops -> (B, J, H/4, W/4); pretrained None | imagenet | file."""

    def __init__(
        self, depth: int = 50, num_joints: int = NUM_JOINTS, se: bool = False, pretrained: str | Path | None = None
    ) -> None:
        super().__init__()
        self.preact = ResNet(depth, se=se)
        if pretrained == IMAGENET:
            load_imagenet(self.preact)
        elif pretrained:
            load_pretrained(self.preact, pretrained)
        c = self.preact.out_channels // 4
        self.shuffle1 = nn.PixelShuffle(2)
        self.duc1 = DUC(c, 2 * c)
        self.duc2 = DUC(c // 2, c)
        self.conv_out = nn.Conv2d(c // 4, num_joints, kernel_size=3, padding=1)
        self.num_joints = num_joints
        nn.init.normal_(self.conv_out.weight, std=0.001)
        nn.init.zeros_(self.conv_out.bias)

    def forward(self, x: Tensor) -> Tensor:
        """(B, 3, H, W) -> (B, num_joints, H/4, W/4); H and W multiples of 32."""
        if x.shape[-2] % 32 or x.shape[-1] % 32:
            raise ValueError(f"FastPose input height and width must be multiples of 32, got {tuple(x.shape[2:])}")
        return self.conv_out(self.duc2(self.duc1(self.shuffle1(self.preact(x)))))
