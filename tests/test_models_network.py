"""FastPose network and the torchvision-compatible ResNet trunk."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from data.keypoints import NUM_JOINTS
from models.fastpose import FastPose
from models.resnet import ResNet, load_pretrained

_COUNTS = {18: (2, 2, 2, 2), 50: (3, 4, 6, 3), 101: (3, 4, 23, 3)}
Checkpoint = tuple[Path, dict[str, torch.Tensor]]


def _bn(prefix: str, c: int) -> dict[str, tuple[int, ...]]:
    return {
        f"{prefix}.weight": (c,),
        f"{prefix}.bias": (c,),
        f"{prefix}.running_mean": (c,),
        f"{prefix}.running_var": (c,),
        f"{prefix}.num_batches_tracked": (),
    }


def _block(prefix: str, cin: int, planes: int, bottleneck: bool, first: bool) -> dict[str, tuple[int, ...]]:
    """Keys of one torchvision block: BasicBlock (3x3, 3x3) or Bottleneck (1x1, 3x3, 1x1 x4)."""
    if bottleneck:
        convs = [(cin, planes, 1), (planes, planes, 3), (planes, 4 * planes, 1)]
    else:
        convs = [(cin, planes, 3), (planes, planes, 3)]
    out: dict[str, tuple[int, ...]] = {}
    for i, (a, b, k) in enumerate(convs, start=1):
        out[f"{prefix}.conv{i}.weight"] = (b, a, k, k)
        out.update(_bn(f"{prefix}.bn{i}", b))
    cout = convs[-1][1]
    if first and (cin != cout or not prefix.startswith("layer1.")):
        out[f"{prefix}.downsample.0.weight"] = (cout, cin, 1, 1)
        out.update(_bn(f"{prefix}.downsample.1", cout))
    return out


def torchvision_resnet_shapes(depth: int) -> dict[str, tuple[int, ...]]:
    """{name: shape} of torchvision's resnet{depth} state dict, fc included, written from the rules."""
    bottleneck = depth >= 50
    shapes: dict[str, tuple[int, ...]] = {"conv1.weight": (64, 3, 7, 7), **_bn("bn1", 64)}
    cin = 64
    for stage, (planes, count) in enumerate(zip((64, 128, 256, 512), _COUNTS[depth]), start=1):
        for i in range(count):
            shapes.update(_block(f"layer{stage}.{i}", cin, planes, bottleneck, i == 0))
            cin = planes * (4 if bottleneck else 1)
    shapes.update({"fc.weight": (1000, cin), "fc.bias": (1000,)})
    return shapes


def _random_checkpoint(shapes: dict[str, tuple[int, ...]], path: Path) -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(0)
    state = {
        k: (
            torch.randint(0, 100, s, generator=gen)
            if k.endswith("num_batches_tracked")
            else torch.randn(s, generator=gen)
        )
        for k, s in shapes.items()
    }
    torch.save(state, path)
    return state


@pytest.fixture(scope="module")
def resnet50_file(tmp_path_factory: pytest.TempPathFactory) -> Checkpoint:
    """A random checkpoint with torchvision's resnet50 names, written once for the module."""
    path = tmp_path_factory.mktemp("ckpt") / "resnet50.pth"
    return path, _random_checkpoint(torchvision_resnet_shapes(50), path)


@pytest.mark.parametrize("depth, size", [(18, (256, 192)), (18, (320, 256)), (50, (256, 192)), (50, (320, 256))])
def test_output_shape_is_stride_4(depth: int, size: tuple[int, int]) -> None:
    net = FastPose(depth=depth).eval()
    with torch.no_grad():
        out = net(torch.zeros(1, 3, *size))
    assert out.shape == (1, NUM_JOINTS, size[0] // 4, size[1] // 4)


def test_input_not_multiple_of_32_is_refused() -> None:
    with pytest.raises(ValueError, match="multiples of 32"):
        FastPose(depth=18)(torch.zeros(1, 3, 64, 48))


def test_trunk_output_channels_and_stride() -> None:
    for depth, channels in [(18, 512), (50, 2048)]:
        trunk = ResNet(depth).eval()
        assert trunk.out_channels == channels
        with torch.no_grad():
            assert trunk(torch.zeros(2, 3, 64, 96)).shape == (2, channels, 2, 3)


@pytest.mark.parametrize("depth", [18, 50, 101])
def test_state_dict_names_and_shapes_match_torchvision(depth: int) -> None:
    expected = {k: s for k, s in torchvision_resnet_shapes(depth).items() if not k.startswith("fc.")}
    got = {k: tuple(v.shape) for k, v in ResNet(depth).state_dict().items()}
    assert got == expected


@pytest.mark.parametrize("depth", [18, 50])
def test_load_pretrained_copies_every_tensor(depth: int, tmp_path: Path, resnet50_file: Checkpoint) -> None:
    if depth == 50:
        path, saved = resnet50_file
    else:
        path = tmp_path / "resnet18.pth"
        saved = _random_checkpoint(torchvision_resnet_shapes(18), path)
    trunk = ResNet(depth)
    assert load_pretrained(trunk, path) == []
    own = trunk.state_dict()
    assert set(own) == {k for k in saved if not k.startswith("fc.")}
    for name, tensor in own.items():
        assert torch.equal(tensor, saved[name]), name


def test_load_into_se_trunk_keeps_se_keys_new(resnet50_file: Checkpoint) -> None:
    path, saved = resnet50_file
    torch.manual_seed(1)
    trunk = ResNet(50, se=True)
    se_before = {k: v.clone() for k, v in trunk.state_dict().items() if ".se." in k}
    assert se_before and "layer1.0.se.fc.0.weight" in se_before
    new = load_pretrained(trunk, path)
    assert new == sorted(se_before)
    own = trunk.state_dict()
    for name, tensor in own.items():
        expected = se_before[name] if ".se." in name else saved[name]
        assert torch.equal(tensor, expected), name


def test_fastpose_pretrained_argument_loads_trunk(tmp_path: Path) -> None:
    path = tmp_path / "resnet18.pth"
    saved = _random_checkpoint(torchvision_resnet_shapes(18), path)
    net = FastPose(depth=18, pretrained=str(path))
    assert torch.equal(net.preact.conv1.weight, saved["conv1.weight"])
    assert torch.equal(net.preact.layer4[1].bn2.running_var, saved["layer4.1.bn2.running_var"])


def test_missing_key_error_names_file_and_key(tmp_path: Path) -> None:
    shapes = torchvision_resnet_shapes(18)
    del shapes["layer2.0.downsample.0.weight"]
    path = tmp_path / "broken.pth"
    _random_checkpoint(shapes, path)
    with pytest.raises(ValueError, match=r"broken\.pth.*layer2\.0\.downsample\.0\.weight"):
        load_pretrained(ResNet(18), path)


def test_wrong_shape_and_wrong_depth_raise(tmp_path: Path, resnet50_file: Checkpoint) -> None:
    shapes = torchvision_resnet_shapes(18)
    shapes["conv1.weight"] = (64, 3, 3, 3)
    path = tmp_path / "badshape.pth"
    _random_checkpoint(shapes, path)
    with pytest.raises(ValueError, match=r"badshape\.pth.*conv1\.weight"):
        load_pretrained(ResNet(18), path)
    with pytest.raises(ValueError, match=r"resnet50\.pth.*unexpected keys \['layer1\.0\.bn3"):
        load_pretrained(ResNet(18), resnet50_file[0])


def test_unreadable_file_error_names_file(tmp_path: Path) -> None:
    path = tmp_path / "garbage.pth"
    path.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match=r"garbage\.pth"):
        load_pretrained(ResNet(18), path)
    with pytest.raises(ValueError, match=r"absent\.pth"):
        load_pretrained(ResNet(18), tmp_path / "absent.pth")


def test_trunk_parameter_counts_match_torchvision() -> None:
    def count(m: torch.nn.Module) -> int:
        return sum(p.numel() for p in m.parameters())

    assert count(ResNet(50)) == 25_557_032 - 2_049_000
    assert count(ResNet(18)) == 11_689_512 - 513_000


def test_gradient_reaches_first_conv() -> None:
    torch.manual_seed(0)
    net = FastPose(depth=18, se=True)
    out = net(torch.randn(2, 3, 64, 32))
    assert out.shape == (2, NUM_JOINTS, 16, 8)
    out.square().sum().backward()
    grad = net.preact.conv1.weight.grad
    assert grad is not None and grad.abs().sum() > 0
    assert net.preact.layer1[0].se.fc[0].weight.grad.abs().sum() > 0


@pytest.mark.parametrize("name, depth", [("fastpose_r18", 18), ("fastpose_r50", 50), ("fastpose_r101", 101)])
def test_model_configs_build_their_depth(name: str, depth: int) -> None:
    from hydra import compose, initialize_config_dir
    from hydra.utils import instantiate

    configs = Path(__file__).resolve().parents[1] / "configs"
    with initialize_config_dir(config_dir=str(configs), version_base="1.3"):
        cfg = compose("train", overrides=[f"model={name}", "model.se=true"])
    net = instantiate(cfg.model)
    assert isinstance(net, FastPose) and net.preact.depth == depth and net.num_joints == NUM_JOINTS
    assert hasattr(net.preact.layer1[0], "se")
