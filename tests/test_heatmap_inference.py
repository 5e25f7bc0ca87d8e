"""Flip test (models/heatmap_inference.py): a mirror-equivariant network gives the same heatmaps with and without
it (the alignment is exact for this codec), the mirrored-back heatmaps swap left and right (feet included)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from data.keypoints import FLIP_PAIRS, NUM_JOINTS, flip_permutation
from models.candidates import find_candidates
from models.heatmap_inference import flip_back, predict_heatmaps


class BlobFinder(nn.Module):
    """A stand-in network that is exactly mirror-equivariant: every joint channel is the crop's brightness
    averaged over each stride-4 cell (heatmap pixel i = input pixels 4i .. 4i + 3, the codec's convention)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, 3, H, W) -> (B, 23, H/4, W/4)."""
        return F.avg_pool2d(x.mean(1, keepdim=True), 4).expand(-1, NUM_JOINTS, -1, -1)


def blob_crops(centres: list[tuple[float, float]], size: tuple[int, int] = (48, 64)) -> torch.Tensor:
    """Crops (B, 3, h, w) with a Gaussian blob (std 6 px) at each sub-pixel (x, y) input position."""
    w, h = size
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij")
    blobs = [torch.exp(-((xs - x) ** 2 + (ys - y) ** 2) / (2 * 6.0**2)) for x, y in centres]
    return torch.stack(blobs)[:, None].expand(-1, 3, -1, -1).contiguous()


def test_equivariant_network_gives_the_same_heatmaps_and_peaks_with_flip_test():
    crops = blob_crops([(13.3, 20.8), (30.0, 41.6), (5.2, 9.0)])
    model = BlobFinder()
    plain = predict_heatmaps(model, crops, batch_size=2, flip_test=False)
    flipped = predict_heatmaps(model, crops, batch_size=2, flip_test=True)
    torch.testing.assert_close(flipped, plain, rtol=0, atol=1e-6)
    xy_plain, _ = find_candidates(plain, threshold=0.01, top_m=1)
    xy_flip, _ = find_candidates(flipped, threshold=0.01, top_m=1)
    np.testing.assert_allclose(xy_flip.numpy(), xy_plain.numpy(), atol=1e-4)
    # a SimpleBaseline-style one-pixel shift of the mirrored-back heatmaps moves the peak by about half a pixel
    shifted = (plain + torch.roll(plain, 1, dims=-1)) / 2
    xy_shifted, _ = find_candidates(shifted, threshold=0.01, top_m=1)
    assert np.abs(xy_shifted.numpy() - xy_plain.numpy())[..., 0].min() > 0.3


def test_flip_back_mirrors_and_swaps_left_and_right_feet_included():
    heatmaps = torch.rand(2, NUM_JOINTS, 5, 4)
    back = flip_back(heatmaps)
    assert {(17, 20), (18, 21), (19, 22)} <= set(FLIP_PAIRS)
    for a, b in FLIP_PAIRS:
        torch.testing.assert_close(back[:, a], heatmaps[:, b].flip(-1), rtol=0, atol=0)
        torch.testing.assert_close(back[:, b], heatmaps[:, a].flip(-1), rtol=0, atol=0)
    torch.testing.assert_close(back[:, 0], heatmaps[:, 0].flip(-1), rtol=0, atol=0)  # nose: mirrored only
    torch.testing.assert_close(flip_back(back), heatmaps, rtol=0, atol=0)
    assert sorted(flip_permutation()) == list(range(NUM_JOINTS))


def test_flip_test_output_is_left_right_consistent_for_a_symmetric_crop():
    # a crop equal to its mirror: whatever the network, the flip-tested right channels are the mirrored left ones
    torch.manual_seed(0)
    half = torch.rand(2, 3, 64, 24)
    crops = torch.cat([half, half.flip(-1)], dim=-1)
    model = nn.Sequential(nn.Conv2d(3, 8, 5, padding=2), nn.ReLU(), nn.Conv2d(8, NUM_JOINTS, 4, stride=4)).eval()
    heatmaps = predict_heatmaps(model, crops, batch_size=4, flip_test=True)
    plain = predict_heatmaps(model, crops, batch_size=4, flip_test=False)
    perm = torch.as_tensor(flip_permutation())
    torch.testing.assert_close(heatmaps[:, perm], heatmaps.flip(-1), rtol=0, atol=1e-6)
    assert not torch.allclose(plain[:, perm], plain.flip(-1), atol=1e-3)  # the network alone is not consistent


def test_bad_batch_size_and_channel_count_are_refused():
    with pytest.raises(ValueError, match="batch_size"):
        predict_heatmaps(BlobFinder(), blob_crops([(3.0, 4.0)]), batch_size=0)
    with pytest.raises(ValueError, match="23 COCO-23 channels"):
        flip_back(torch.zeros(1, 17, 4, 4))
