"""Multi-modal heatmap targets of Eq. 1 (T + mu C) and their decoding; x_hm = (x_in + 0.5) * w / W - 0.5."""

from __future__ import annotations

import numpy as np
import torch
from scipy.ndimage import gaussian_filter

from data.keypoints import NUM_JOINTS
from data.pose2d.crop_transforms import transform_points

_LOG_EPS = 1e-10


class MultiModalHeatmapCodec:
    """Encode a person's crop into (23, h, w) targets and decode heatmaps; sizes (w, h), sigma in heatmap px."""

    def __init__(
        self,
        input_size: tuple[int, int] = (192, 256),
        heatmap_size: tuple[int, int] = (48, 64),
        sigma: float = 2.0,
        mu: float = 0.5,
    ) -> None:
        self.input_size = (int(input_size[0]), int(input_size[1]))
        self.heatmap_size = (int(heatmap_size[0]), int(heatmap_size[1]))
        self.sigma = float(sigma)
        self.mu = float(mu)
        self._ratio = np.array(self.heatmap_size, dtype=np.float64) / np.array(self.input_size)

    def heatmap_to_input(self, points: np.ndarray) -> np.ndarray:
        """Heatmap pixels (..., 2) -> crop-input pixels (..., 2)."""
        return (np.asarray(points, dtype=np.float64) + 0.5) / self._ratio - 0.5

    def inside(self, points: np.ndarray) -> np.ndarray:
        """Whether crop-input points (..., 2) lie on the crop, edges included -> (...,) bool."""
        points = np.asarray(points, dtype=np.float64)
        size = np.array(self.input_size, dtype=np.float64)
        return np.all((points >= -0.5) & (points <= size - 0.5), axis=-1)

    def gaussians(self, points: np.ndarray) -> np.ndarray:
        """Unit-peak Gaussians at sub-pixel crop-input points (..., 2) -> (..., h, w) float64."""
        centres = (np.asarray(points, dtype=np.float64) + 0.5) * self._ratio - 0.5
        w, h = self.heatmap_size
        xs, ys = np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)
        gx = np.exp(-((xs - centres[..., 0:1]) ** 2) / (2 * self.sigma**2))
        gy = np.exp(-((ys - centres[..., 1:2]) ** 2) / (2 * self.sigma**2))
        return gy[..., :, None] * gx[..., None, :]

    def encode(self, own: np.ndarray, others: np.ndarray, labelled: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Own (23, 3), others (M, 23, 3) x, y, v, labelled (23,) -> target T + mu C (23, h, w), weight (23,)."""
        own = np.asarray(own, dtype=np.float64).reshape(NUM_JOINTS, 3)
        others = np.asarray(others, dtype=np.float64).reshape(-1, NUM_JOINTS, 3)
        labelled = np.asarray(labelled, dtype=bool).reshape(NUM_JOINTS)
        own_present = labelled & (own[:, 2] > 0) & self.inside(own[:, :2])
        others_present = labelled & (others[..., 2] > 0) & self.inside(others[..., :2])  # (M, 23)
        target = self.gaussians(own[:, :2]) * own_present[:, None, None]
        if len(others) and self.mu != 0:
            crowd = self.gaussians(others[..., :2]) * others_present[..., None, None]
            target = target + self.mu * crowd.max(axis=0)
        weight = own_present | others_present.any(axis=0)  # not clipped: it would flatten peaks where people meet
        return target.astype(np.float32), weight.astype(np.float32)

    def encode_crop(
        self, keypoints_all: np.ndarray, own_index: int, affine: np.ndarray, labelled: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Person own_index of keypoints_all (N, 23, 3) image px, image-to-crop affine (2, 3) -> target, weight."""
        keypoints = np.array(keypoints_all, dtype=np.float64).reshape(-1, NUM_JOINTS, 3)
        keypoints[..., :2] = transform_points(keypoints[..., :2], affine)
        return self.encode(keypoints[own_index], np.delete(keypoints, own_index, axis=0), labelled)

    def decode(self, heatmaps: np.ndarray | torch.Tensor, modulate: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Heatmaps (..., 23, h, w) -> keypoints (..., 23, 2) crop-input px, scores (..., 23): argmax + DARK step."""
        if isinstance(heatmaps, torch.Tensor):
            heatmaps = heatmaps.detach().cpu().numpy()
        heatmaps = np.asarray(heatmaps, dtype=np.float64)
        lead, (h, w) = heatmaps.shape[:-2], heatmaps.shape[-2:]
        flat = heatmaps.reshape(-1, h, w)
        index = flat.reshape(len(flat), -1).argmax(axis=1)
        px, py = index % w, index // w
        scores = flat[np.arange(len(flat)), py, px]
        offsets = _newton_offsets(np.log(np.maximum(flat, _LOG_EPS)), px, py)
        if modulate:  # blur first, except within 2 sigma of the border, where the zero-padded blur drags peaks inward
            margin = int(np.ceil(2 * self.sigma))
            far = (px >= margin) & (px < w - margin) & (py >= margin) & (py < h - margin)
            blurred = _newton_offsets(np.log(np.maximum(_modulate(flat, self.sigma), _LOG_EPS)), px, py)
            offsets = np.where(far[:, None], blurred, offsets)
        points = np.stack([px, py], axis=-1) + offsets
        return self.heatmap_to_input(points).reshape(*lead, 2), scores.reshape(lead)


def _modulate(heatmaps: np.ndarray, sigma: float) -> np.ndarray:
    """Blur heatmaps (K, h, w) with a zero-padded Gaussian of std sigma, keeping each channel's maximum."""
    blurred = gaussian_filter(heatmaps, sigma=(0, sigma, sigma), mode="constant")
    peak = heatmaps.max(axis=(1, 2), keepdims=True)
    return blurred * peak / np.maximum(blurred.max(axis=(1, 2), keepdims=True), _LOG_EPS)


def _newton_offsets(log_maps: np.ndarray, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """Sub-pixel offsets (K, 2) of the maxima of log heatmaps (K, h, w) around integer argmaxes (K,)."""
    k = np.arange(len(log_maps))
    h, w = log_maps.shape[1:]
    xm, xp = np.clip(px - 1, 0, w - 1), np.clip(px + 1, 0, w - 1)
    ym, yp = np.clip(py - 1, 0, h - 1), np.clip(py + 1, 0, h - 1)
    centre = log_maps[k, py, px]
    ok_x, ok_y = (px > 0) & (px < w - 1), (py > 0) & (py < h - 1)
    # An axis without both neighbours gets a zero gradient and a unit curvature: no step along it.
    dx = np.where(ok_x, (log_maps[k, py, xp] - log_maps[k, py, xm]) / 2, 0.0)
    dy = np.where(ok_y, (log_maps[k, yp, px] - log_maps[k, ym, px]) / 2, 0.0)
    dxx = np.where(ok_x, log_maps[k, py, xp] - 2 * centre + log_maps[k, py, xm], -1.0)
    dyy = np.where(ok_y, log_maps[k, yp, px] - 2 * centre + log_maps[k, ym, px], -1.0)
    dxy = np.where(
        ok_x & ok_y, (log_maps[k, yp, xp] - log_maps[k, yp, xm] - log_maps[k, ym, xp] + log_maps[k, ym, xm]) / 4, 0.0
    )
    det = dxx * dyy - dxy**2
    concave = (dxx < 0) & (det > 0)
    safe_det = np.where(concave, det, 1.0)
    off_x = -(dyy * dx - dxy * dy) / safe_det
    off_y = -(dxx * dy - dxy * dx) / safe_det
    return np.clip(np.stack([off_x, off_y], axis=-1) * concave[:, None], -0.5, 0.5)
