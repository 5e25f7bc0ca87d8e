import pytest
import torch

from models.loss import WeightedHeatmapLoss


def small_case() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """B = 1, 23 channels of 2 x 2 pixels with a few non-zero entries."""
    pred, target, weight = torch.zeros(1, 23, 2, 2), torch.zeros(1, 23, 2, 2), torch.ones(1, 23)
    pred[0, 0] = torch.tensor([[1.0, 0.0], [0.0, 0.0]])  # body: MSE (1^2) / 4 = 0.25
    target[0, 3] = torch.tensor([[0.0, 2.0], [0.0, 0.0]])  # body: MSE (2^2) / 4 = 1.0, weight 0.5 -> 0.5
    weight[0, 3] = 0.5
    pred[0, 7] = torch.tensor([[3.0, 3.0], [3.0, 3.0]])  # body: MSE 9, weight 0 -> 0
    weight[0, 7] = 0.0
    target[0, 17] = torch.tensor([[1.0, 1.0], [0.0, 0.0]])  # foot: MSE 2 / 4 = 0.5
    pred[0, 22] = torch.tensor([[0.0, 0.0], [1.0, -1.0]])  # foot: MSE 2 / 4 = 0.5
    return pred, target, weight


def test_loss_equals_hand_computed_value():
    out = WeightedHeatmapLoss(foot_weight=1.5)(*small_case())
    # Eq. 1: (sum_body + 1.5 sum_foot) / (17 + 6 * 1.5) = (0.25 + 0.5 + 1.5 * (0.5 + 0.5)) / 26 = 2.25 / 26
    assert out["loss"].item() == pytest.approx(2.25 / 26)
    assert out["body"].item() == pytest.approx(0.75 / 17)
    assert out["foot"].item() == pytest.approx(1.0 / 6)
    assert out["loss"].item() == pytest.approx((17 * out["body"] + 6 * 1.5 * out["foot"]).item() / 26)


def test_lambda_one_is_the_plain_mean_of_weighted_channel_mses():
    generator = torch.Generator().manual_seed(0)
    pred, target = torch.rand(3, 23, 4, 5, generator=generator), torch.rand(3, 23, 4, 5, generator=generator)
    weight = (torch.rand(3, 23, generator=generator) > 0.3).float()
    out = WeightedHeatmapLoss(foot_weight=1.0)(pred, target, weight)
    expected = (((pred - target) ** 2).mean(dim=(2, 3)) * weight).mean()
    assert out["loss"].item() == pytest.approx(expected.item(), rel=1e-6)


def test_batch_mean_and_foot_weight_shift_attention_to_feet():
    pred, target, weight = small_case()
    batch = [torch.cat([pred, pred * 0]), torch.cat([target, target * 0]), torch.cat([weight, weight])]
    loss = WeightedHeatmapLoss(foot_weight=1.5)
    assert loss(*batch)["loss"].item() == pytest.approx(loss(pred, target, weight)["loss"].item() / 2)
    assert (
        WeightedHeatmapLoss(3.0)(pred, target, weight)["loss"] > WeightedHeatmapLoss(1.0)(pred, target, weight)["loss"]
    )


def test_zero_weight_channel_gets_no_gradient():
    pred, target, weight = small_case()
    pred.requires_grad_(True)
    WeightedHeatmapLoss()(pred, target, weight)["loss"].backward()
    assert torch.all(pred.grad[0, 7] == 0) and torch.any(pred.grad[0, 0] != 0)


def test_rejects_wrong_shapes():
    pred, target, weight = small_case()
    with pytest.raises(ValueError):
        WeightedHeatmapLoss()(pred[:, :17], target[:, :17], weight[:, :17])
    with pytest.raises(ValueError):
        WeightedHeatmapLoss()(pred, target, weight[:, :5])
