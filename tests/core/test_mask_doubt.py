"""Where a learned mask is in doubt, and how training can weigh those pixels less in its losses."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cadnerf_core.config import internal_config
from cadnerf_core.intake.crop import canonical_box
from cadnerf_core.intake.masks import doubt_map, photo_masks
from cadnerf_core.intake.photos import Photo, doubt_weights
from cadnerf_core.nerf import losses
from cadnerf_core.nerf.state import TrainData
from cadnerf_core.pipeline import Intake, training_data
from cadnerf_core.retrieval.result import PhotoMatch, RetrievalResult
from tests.core.test_masks import _object_scene, needs_learned


def test_doubt_map_marks_where_the_cut_and_the_first_look_disagree_inside_the_box() -> None:
    first = np.zeros((40, 80), np.float32)  # the whole photo, first pass
    first[10:30, 20:60] = 0.9  # the first look: a 20 x 40 object
    cut = np.ones((20, 40), bool)  # the refined cut of the box (rows 10:30, cols 20:60)
    cut[:, 30:] = False  # it dropped the object's right quarter
    box = (10 / 40, 30 / 40, 20 / 80, 60 / 80)
    doubt = doubt_map(cut, first, box, (160, 80))  # kept at twice the first pass's size
    assert doubt.shape == (80, 160)
    assert doubt[20:60, 100:120].all()  # the dropped quarter
    assert not doubt[20:60, 40:100].any()  # where both agree
    assert not doubt[:20].any() and not doubt[60:].any()  # outside the box


def test_doubt_weights_are_zero_where_in_doubt_in_the_canonical_crop() -> None:
    mask = np.zeros((200, 300), bool)
    mask[50:150, 100:200] = True
    doubt = np.zeros((100, 150), bool)  # the doubt map at half the photo's size
    doubt[25:50, 50:100] = True  # the top half of the object
    box = canonical_box(mask, 32, 0.1)
    weights = doubt_weights([doubt, None], [mask.shape, mask.shape], [box, box])
    assert weights is not None and weights.shape == (2, 32, 32)
    # The object fills rows and columns 3.2 to 28.8 of the crop: its top half weighs 0.
    assert weights[0, 5:14, 5:27].max() < 1e-6
    assert weights[0, 18:30, :].min() > 1 - 1e-6 and weights[0, :, :2].min() > 1 - 1e-6
    assert weights[1].min() == 1.0  # a photo without doubts
    assert doubt_weights([None, None], [mask.shape] * 2, [box, box]) is None
    # A doubtful pixel weighing a share of a sure one; weighing as much: no weights at all.
    half = doubt_weights([doubt, None], [mask.shape, mask.shape], [box, box], 0.25)
    assert half is not None
    assert half[0, 5:14, 5:27] == pytest.approx(np.full((9, 22), 0.25), abs=1e-6)
    assert half[0, 18:30, :].min() > 1 - 1e-6
    assert doubt_weights([doubt, None], [mask.shape, mask.shape], [box, box], 1.0) is None


def _intake_with_doubts() -> Intake:
    """A two-photo intake whose first learned mask is in doubt over its object's top half."""
    rng = np.random.default_rng(0)
    mask = np.zeros((80, 120), bool)
    mask[20:60, 40:80] = True
    doubt = np.zeros((80, 120), bool)
    doubt[20:40, 40:80] = True
    photos = [Photo(f"p{i}.png", rng.random((80, 120, 3), dtype=np.float32)) for i in range(2)]
    box = canonical_box(mask, 16, 0.1)
    K = np.array([[20.0, 0, 8], [0, 20.0, 8], [0, 0, 1]])
    matches = [PhotoMatch(i, p.name, 0, 0.0, 0.0, 0.9, False, np.eye(4), K, box, K)
               for i, p in enumerate(photos)]
    retrieval = RetrievalResult("m", "c", [], matches, "dp", 1, 1.0)
    return Intake([p.name for p in photos], photos, [mask, mask], retrieval, [doubt, None])


def test_a_jobs_doubt_weight_decides_the_weights_training_gets() -> None:
    intake = _intake_with_doubts()
    cpu = torch.device("cpu")
    counted = training_data(intake, internal_config("preview"), 0.1, cpu)
    assert counted.weights is None  # the default: doubtful pixels count as any other
    left_out = training_data(intake, internal_config("preview", {"masks.doubt_weight": 0}), 0.1,
                             cpu)
    assert left_out.weights is not None
    half = left_out.height // 2  # the object fills the crop but for its margin
    assert left_out.weights[0, half // 2:half - 2, half // 2:-half // 2].max().item() == 0.0
    assert left_out.weights[0, half + 2:].min().item() == 1.0  # its sure bottom half
    assert left_out.weights[1].min().item() == 1.0  # the second photo has no doubt map
    with pytest.raises(ValueError):
        internal_config("preview", {"masks.doubt_weight": 1.5})


def test_weighted_mse_counts_each_ray_by_its_weight() -> None:
    pred = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.5, 0.5, 0.5]])
    target = torch.zeros(3, 3)
    assert losses.weighted_mse(pred, target, None).item() == pytest.approx(1.25 / 3)
    weight = torch.tensor([1.0, 0.0, 1.0])
    assert losses.weighted_mse(pred, target, weight).item() == pytest.approx(0.125)
    assert losses.weighted_mse(pred[:, 0], target[:, 0], weight).item() == pytest.approx(0.125)
    none = losses.weighted_mse(pred, target, torch.zeros(3))
    assert none.item() == 0.0


def test_a_pixel_weighing_zero_gives_no_gradient() -> None:
    images = torch.rand(1, 4, 4, 3)
    masks = torch.zeros(1, 4, 4)
    weights = torch.ones(1, 4, 4)
    weights[0, 1, 2] = 0.0
    data = TrainData(images, masks, torch.eye(3)[None], weights=weights)
    img, x, y = torch.tensor([0, 0]), torch.tensor([2, 3]), torch.tensor([1, 1])
    acc = torch.tensor([0.7, 0.2], requires_grad=True)
    loss = losses.weighted_mse(acc, data.masks[img, y, x], losses.pixel_weights(data, img, x, y))
    loss.backward()
    assert acc.grad is not None
    assert acc.grad[0].item() == 0.0 and acc.grad[1].item() == pytest.approx(0.4)
    assert losses.pixel_weights(TrainData(images, masks, torch.eye(3)[None]), img, x, y) is None


@needs_learned
def test_only_a_learned_mask_carries_a_doubt_map() -> None:
    photo, truth = _object_scene(True)
    learned, grabcut = photo_masks([photo], "learned")[0], photo_masks([photo], "grabcut")[0]
    assert learned.doubt is not None and learned.doubt.dtype == bool
    height, width = truth.shape
    assert learned.doubt.shape[1] / learned.doubt.shape[0] == pytest.approx(width / height,
                                                                            rel=0.02)
    assert learned.doubt.mean() < 0.1  # an easy object: the two looks mostly agree
    assert grabcut.doubt is None
    uploaded = photo_masks([Photo("own.png", photo.rgb, truth, mask_source="uploaded")])[0]
    assert uploaded.doubt is None
