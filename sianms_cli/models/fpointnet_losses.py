"""The Frustum PointNets loss (FPN-TF ``model_util.get_loss``) and its encodings.

docs/methods.md#frustum-pointnets-loss describes the loss.
Targets travel raw: centre (B, 3) and heading (B,) in the frustum frame, size (B, 3) as
(l, w, h) and the size cluster (B,) (= the class: one cluster per class). The heading-bin and
size-residual labels are encoded here, so the dataset never holds a second copy of them.

Total = mask + λ (centre + stage-1 centre + heading class + size class + 20 heading residual
+ 20 size residual + 10 corner), λ = 1 (``box_weight``), corner weight 10. The original
adds the predicted size residual to the mean size twice when it builds the corners (issues
#43, #49, #112 of charlesq34/frustum-pointnets); here it is added once.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

RESIDUAL_WEIGHT = 20.0  # on the heading and size residual terms, as the released code


def angle_to_class(angle: torch.Tensor, num_bins: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Heading bin and residual (radians, in [-half bin, half bin)) of each angle.

    Bin k is centred at k * 2π/NH (bin 0 on 0): the angle is wrapped to [0, 2π), shifted by
    half a bin, floored to a bin; the residual is the rest (docs/methods.md#heading-bins-and-size-clusters).
    """
    width = 2 * math.pi / num_bins
    shifted = torch.remainder(torch.remainder(angle, 2 * math.pi) + width / 2, 2 * math.pi)
    bins = torch.floor(shifted / width).long().clamp(max=num_bins - 1)
    return bins, shifted - (bins.to(angle.dtype) * width + width / 2)


def class_to_angle(bins: torch.Tensor, residual: torch.Tensor, num_bins: int) -> torch.Tensor:
    """Heading from bin and residual (radians), wrapped to (-π, π]."""
    angle = bins.to(residual.dtype) * (2 * math.pi / num_bins) + residual
    return math.pi - torch.remainder(math.pi - angle, 2 * math.pi)


def box_corners(center: torch.Tensor, heading: torch.Tensor, lwh: torch.Tensor) -> torch.Tensor:
    """(B, 8, 3) corners in the original's order (docs/methods.md#box-corners), frustum/camera frame.

    Before rotation x = ±l/2, y = ±h/2, z = ±w/2; rotated by R_y(heading) =
    [[c, 0, s], [0, 1, 0], [-s, 0, c]], then moved to the centre.
    """
    l, w, h = lwh[:, 0:1], lwh[:, 1:2], lwh[:, 2:3]
    sx = lwh.new_tensor([1, 1, -1, -1, 1, 1, -1, -1])
    sy = lwh.new_tensor([1, 1, 1, 1, -1, -1, -1, -1])
    sz = lwh.new_tensor([1, -1, -1, 1, 1, -1, -1, 1])
    x, y, z = sx * l / 2, sy * h / 2, sz * w / 2
    c, s = torch.cos(heading)[:, None], torch.sin(heading)[:, None]
    return torch.stack([c * x + s * z, y, -s * x + c * z], dim=2) + center[:, None, :]


def huber(error: torch.Tensor, delta: float) -> torch.Tensor:
    """Mean of 0.5 min(|e|, δ)² + δ (|e| - min(|e|, δ)) over all elements (the original's form)."""
    absolute = error.abs()
    quadratic = absolute.clamp(max=delta)
    return (0.5 * quadratic ** 2 + delta * (absolute - quadratic)).mean()


def decode_boxes(outputs: dict[str, torch.Tensor], mean_sizes: torch.Tensor,
                 num_bins: int) -> dict[str, torch.Tensor]:
    """The predicted box: centre, heading of the best bin + its residual, size of the best cluster."""
    heading_bin = outputs["heading_scores"].argmax(dim=1)
    residual = outputs["heading_residuals"].gather(1, heading_bin[:, None])[:, 0]
    size_class = outputs["size_scores"].argmax(dim=1)
    size = mean_sizes[size_class] + outputs["size_residuals"][torch.arange(len(size_class)), size_class]
    return {"center": outputs["center"], "heading": class_to_angle(heading_bin, residual, num_bins),
            "lwh": size, "size_class": size_class}


def fpointnet_loss(outputs: dict[str, torch.Tensor], targets: dict[str, torch.Tensor], mean_sizes: torch.Tensor,
                   box_weight: float = 1.0, corner_weight: float = 10.0,
                   heading_class_weight: float = 1.0) -> dict[str, torch.Tensor]:
    """Every term of the loss and ``total`` (scalars).

    Args:
        outputs: :meth:`sianms_cli.models.fpointnet.FPointNetV1.forward`'s dict.
        targets: ``seg`` (B, N) long 0/1, ``center`` (B, 3), ``heading`` (B,),
            ``lwh`` (B, 3) (l, w, h), ``size_class`` (B,) long.
        mean_sizes: (NS, 3) (l, w, h) of the size clusters.
        box_weight: λ; corner_weight: the corner term's weight inside λ; heading_class_weight: the
            heading-bin term's (the original's 1; the only term that tells a box's front from its back).
    """
    num_bins = outputs["heading_scores"].shape[1]
    rows = torch.arange(len(targets["center"]), device=targets["center"].device)
    mask = F.cross_entropy(outputs["seg_logits"].reshape(-1, 2), targets["seg"].reshape(-1))
    center = huber(torch.linalg.vector_norm(targets["center"] - outputs["center"], dim=1), 2.0)
    stage1 = huber(torch.linalg.vector_norm(targets["center"] - outputs["stage1_center"], dim=1), 1.0)

    heading_bin, heading_residual = angle_to_class(targets["heading"], num_bins)
    heading_class = F.cross_entropy(outputs["heading_scores"], heading_bin)
    predicted_normalized = outputs["heading_residuals_normalized"][rows, heading_bin]
    heading_res = huber(predicted_normalized - heading_residual / (math.pi / num_bins), 1.0)

    size_class = targets["size_class"]
    size_cls = F.cross_entropy(outputs["size_scores"], size_class)
    mean = mean_sizes[size_class]
    size_error = outputs["size_residuals_normalized"][rows, size_class] - (targets["lwh"] - mean) / mean
    size_res = huber(torch.linalg.vector_norm(size_error, dim=1), 1.0)

    bin_width = 2 * math.pi / num_bins
    predicted_heading = (heading_bin.to(predicted_normalized.dtype) * bin_width
                         + outputs["heading_residuals"][rows, heading_bin])
    predicted = box_corners(outputs["center"], predicted_heading, mean + outputs["size_residuals"][rows, size_class])
    truth = box_corners(targets["center"], targets["heading"], targets["lwh"])
    flipped = box_corners(targets["center"], targets["heading"] + math.pi, targets["lwh"])
    distance = torch.minimum(torch.linalg.vector_norm(predicted - truth, dim=2),
                             torch.linalg.vector_norm(predicted - flipped, dim=2))
    corner = huber(distance, 1.0)

    box = (center + stage1 + heading_class_weight * heading_class + size_cls
           + RESIDUAL_WEIGHT * (heading_res + size_res) + corner_weight * corner)
    return {"total": mask + box_weight * box, "mask": mask, "center": center, "stage1_center": stage1,
            "heading_class": heading_class, "heading_residual": heading_res, "size_class": size_cls,
            "size_residual": size_res, "corner": corner}
