"""ROI Align in pure torch with torchvision's semantics (``torchvision.ops.roi_align``).

For each ROI and output bin, ``g_h x g_w`` points on a regular grid inside the bin are read
by bilinear interpolation and averaged (docs/methods.md#roi-features):

- ``offset = 0.5 if aligned else 0``; ``x1' = x1 * spatial_scale - offset`` (same for y1,
  x2, y2); ``roi_w = x2' - x1'``; without ``aligned`` roi_w and roi_h are clamped to >= 1;
- ``bin_h = roi_h / PH``; ``g_h = sampling_ratio`` if > 0 else ``ceil(roi_h / PH)`` (per ROI);
- sample ``y = y1' + ph * bin_h + (iy + 0.5) * bin_h / g_h``, likewise x;
- a sample with ``y < -1`` or ``y > H`` (or x outside [-1, W]) reads 0 but still counts in
  the average; otherwise y is clamped to >= 0, and when ``floor(y) >= H - 1`` it reads row
  H - 1 only; bilinear between the 4 neighbouring feature pixels (pixel centres at integer
  coordinates of the feature map);
- bin value = sum of its samples / max(g_h * g_w, 1), so a ROI with g_h or g_w <= 0
  (possible only with ``aligned=True`` and an empty box) gives zeros.

``aligned=True`` is the pixel model where feature pixel i covers [i, i + 1) (detectron2's
ROIAlignV2). Sample coordinates are computed in float64 and the bilinear weights cast to the
features' dtype; the result matches torchvision to rounding.
"""

from __future__ import annotations

import math

import torch

from sianms_cli.errors import SianmsError

_MAX_GATHER = 8_000_000  # elements per gathered chunk (ROIs x samples x channels)


def roi_align(
    features: torch.Tensor,
    boxes: torch.Tensor | list[torch.Tensor],
    output_size: int | tuple[int, int],
    spatial_scale: float = 1.0,
    sampling_ratio: int = -1,
    aligned: bool = True,
) -> torch.Tensor:
    """Pool a fixed-size feature patch for each box.

    Args:
        features: (N, C, H, W) feature maps.
        boxes: (K, 5) [batch index, x1, y1, x2, y2] or a list of N tensors (L_i, 4) [x1, y1,
            x2, y2], in input-image coordinates (multiplied by ``spatial_scale``).
        output_size: PH = PW, or (PH, PW).
        spatial_scale: feature-map pixels per input pixel (1/16 for a stride-16 map).
        sampling_ratio: samples per bin side; <= 0 for the adaptive ``ceil(roi / bins)``.
        aligned: shift by half a pixel (torchvision ``aligned=True``).

    Returns:
        (K, C, PH, PW) in the features' dtype; K = 0 gives an empty tensor.
    """
    if features.dim() != 4:
        raise SianmsError(f"roi_align needs (N, C, H, W) features, got shape {tuple(features.shape)}")
    rois = _as_rois(boxes, features.device)
    ph, pw = (output_size, output_size) if isinstance(output_size, int) else tuple(output_size)
    if ph < 1 or pw < 1:
        raise SianmsError(f"roi_align output size must be positive, got {(ph, pw)}")
    count, channels, height, width = len(rois), features.shape[1], features.shape[2], features.shape[3]
    out = features.new_zeros((count, channels, ph, pw))
    if count == 0:
        return out
    offset = 0.5 if aligned else 0.0
    batch = rois[:, 0].long()
    x1 = rois[:, 1] * spatial_scale - offset
    y1 = rois[:, 2] * spatial_scale - offset
    roi_w = rois[:, 3] * spatial_scale - offset - x1
    roi_h = rois[:, 4] * spatial_scale - offset - y1
    if not aligned:
        roi_w = roi_w.clamp(min=1.0)
        roi_h = roi_h.clamp(min=1.0)
    bin_h, bin_w = roi_h / ph, roi_w / pw
    if sampling_ratio > 0:
        grid_h = torch.full((count,), sampling_ratio, dtype=torch.long)
        grid_w = grid_h.clone()
    else:
        grid_h = torch.ceil(roi_h / ph).long()
        grid_w = torch.ceil(roi_w / pw).long()
    keys = torch.stack([grid_h, grid_w], dim=1)
    for gh, gw in torch.unique(keys, dim=0).tolist():
        if gh <= 0 or gw <= 0:
            continue  # no samples: the bins stay 0
        members = torch.nonzero((keys[:, 0] == gh) & (keys[:, 1] == gw)).flatten()
        per_roi = ph * gh * pw * gw * channels
        step = max(1, _MAX_GATHER // max(per_roi, 1))
        for start in range(0, len(members), step):
            index = members[start:start + step]
            ys, wy_lo, wy_hi, y_lo, y_hi = _axis(y1[index], bin_h[index], ph, gh, height)
            xs, wx_lo, wx_hi, x_lo, x_hi = _axis(x1[index], bin_w[index], pw, gw, width)
            b = batch[index][:, None, None]
            value = features.new_zeros(())  # 0 + the first term, as a Python 0 would add
            for wy, yi in ((wy_lo, y_lo), (wy_hi, y_hi)):
                for wx, xi in ((wx_lo, x_lo), (wx_hi, x_hi)):
                    weight = (wy[:, :, None] * wx[:, None, :]).to(features.dtype)  # (k, Sy, Sx)
                    gathered = features[b, :, yi[:, :, None], xi[:, None, :]]  # (k, Sy, Sx, C)
                    value = value + weight[..., None] * gathered
            value = value.reshape(len(index), ph, gh, pw, gw, channels).sum(dim=(2, 4)) / (gh * gw)
            out[index] = value.permute(0, 3, 1, 2).to(features.dtype)
    return out


def _axis(start: torch.Tensor, bin_size: torch.Tensor, bins: int, grid: int, size: int):
    """Sample coordinates along one axis and their bilinear neighbours and weights.

    Returns (coords, w_low, w_high, i_low, i_high), each (k, bins * grid); weights are 0
    for samples outside [-1, size].
    """
    ph = torch.arange(bins, dtype=torch.float64).repeat_interleave(grid)
    iy = torch.arange(grid, dtype=torch.float64).repeat(bins)
    coords = start[:, None] + ph[None, :] * bin_size[:, None] + (iy[None, :] + 0.5) * bin_size[:, None] / grid
    valid = (coords >= -1.0) & (coords <= size)
    y = coords.clamp(min=0.0)
    low = torch.floor(y).long()
    at_edge = low >= size - 1
    low = torch.where(at_edge, torch.full_like(low, size - 1), low)
    high = torch.where(at_edge, low, low + 1)
    y = torch.where(at_edge, low.to(torch.float64), y)
    frac = y - low.to(torch.float64)
    w_high = torch.where(valid, frac, torch.zeros_like(frac))
    w_low = torch.where(valid, 1.0 - frac, torch.zeros_like(frac))
    return coords, w_low, w_high, low.clamp(0, size - 1), high.clamp(0, size - 1)


def _as_rois(boxes: torch.Tensor | list[torch.Tensor], device: torch.device) -> torch.Tensor:
    if isinstance(boxes, (list, tuple)):
        parts = []
        for i, part in enumerate(boxes):
            part = torch.as_tensor(part, dtype=torch.float64, device=device).reshape(-1, 4)
            parts.append(torch.cat([torch.full((len(part), 1), float(i), dtype=torch.float64), part], dim=1))
        return torch.cat(parts) if parts else torch.zeros((0, 5), dtype=torch.float64)
    rois = torch.as_tensor(boxes, dtype=torch.float64, device=device)
    if rois.dim() != 2 or rois.shape[1] != 5:
        raise SianmsError(f"roi_align boxes must be (K, 5) or a list of (L, 4), got shape {tuple(rois.shape)}")
    return rois


def roi_align_reference(features, rois, output_size, spatial_scale=1.0, sampling_ratio=-1, aligned=True):
    """Slow, loop-by-loop transcription of torchvision's CPU kernel (for tests).

    Args as :func:`roi_align` with ``rois`` (K, 5); returns a float64 (K, C, PH, PW) tensor.
    """
    ph_n, pw_n = (output_size, output_size) if isinstance(output_size, int) else output_size
    feats = features.double()
    _, channels, height, width = feats.shape
    out = torch.zeros((len(rois), channels, ph_n, pw_n), dtype=torch.float64)
    offset = 0.5 if aligned else 0.0

    def bilinear(c_map, y, x):
        if y < -1.0 or y > height or x < -1.0 or x > width:
            return c_map.new_zeros(channels)
        y, x = max(y, 0.0), max(x, 0.0)
        y_low, x_low = int(y), int(x)
        if y_low >= height - 1:
            y_high = y_low = height - 1
            y = float(y_low)
        else:
            y_high = y_low + 1
        if x_low >= width - 1:
            x_high = x_low = width - 1
            x = float(x_low)
        else:
            x_high = x_low + 1
        ly, lx = y - y_low, x - x_low
        hy, hx = 1.0 - ly, 1.0 - lx
        return (hy * hx * c_map[:, y_low, x_low] + hy * lx * c_map[:, y_low, x_high]
                + ly * hx * c_map[:, y_high, x_low] + ly * lx * c_map[:, y_high, x_high])

    for k, roi in enumerate(rois.tolist()):
        b, rx1, ry1, rx2, ry2 = roi
        c_map = feats[int(b)]
        sx, sy = rx1 * spatial_scale - offset, ry1 * spatial_scale - offset
        ex, ey = rx2 * spatial_scale - offset, ry2 * spatial_scale - offset
        rw, rh = ex - sx, ey - sy
        if not aligned:
            rw, rh = max(rw, 1.0), max(rh, 1.0)
        bh, bw = rh / ph_n, rw / pw_n
        gh = sampling_ratio if sampling_ratio > 0 else math.ceil(rh / ph_n)
        gw = sampling_ratio if sampling_ratio > 0 else math.ceil(rw / pw_n)
        count = max(gh * gw, 1)
        for ph in range(ph_n):
            for pw in range(pw_n):
                acc = torch.zeros(channels, dtype=torch.float64)
                for iy in range(max(gh, 0)):
                    y = sy + ph * bh + (iy + 0.5) * bh / gh
                    for ix in range(max(gw, 0)):
                        x = sx + pw * bw + (ix + 0.5) * bw / gw
                        acc += bilinear(c_map, y, x)
                out[k, :, ph, pw] = acc / count
    return out
