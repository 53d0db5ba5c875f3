"""Retrieval: the IoU table, the model vote, and whole retrievals on the tiny library."""

from __future__ import annotations

import json
from typing import Any, Literal

import numpy as np
import pytest

from cadnerf_core.config import RetrievalConfig
from cadnerf_core.retrieval.scoring import azimuth_bins, iou_table, vote_models
from cadnerf_core.retrieval.search import retrieve


def test_iou_table_equals_a_naive_loop() -> None:
    rng = np.random.default_rng(0)
    masks = rng.random((3, 16, 16)) > 0.5
    silhouettes = rng.random((2, 5, 16, 16)) > rng.random((2, 5, 1, 1))
    silhouettes[1, 2] = False  # an empty silhouette: IoU 0, no division by zero
    table = iou_table(masks, silhouettes)
    assert table.shape == (3, 2, 5) and table.dtype == np.float32
    for p in range(3):
        for m in range(2):
            for v in range(5):
                a, b = masks[p], silhouettes[m, v]
                union = (a | b).sum()
                expected = (a & b).sum() / union if union else 0.0
                assert table[p, m, v] == pytest.approx(expected, abs=1e-6)


def test_vote_breaks_ties_by_summed_iou() -> None:
    iou = np.zeros((4, 3, 2))
    iou[0, 0, 0] = iou[1, 0, 1] = 0.9  # two votes for model 0
    iou[2, 1, 0] = iou[3, 1, 1] = 0.8  # two for model 1
    iou[:2, 1, 0] = 0.5  # model 1 is second best on photos 0 and 1
    chosen, ranking = vote_models(iou)
    assert chosen == 1  # same votes, larger summed best IoU (2.6 against 1.8)
    assert [(m, votes) for m, votes, _ in ranking] == [(1, 2), (0, 2), (2, 0)]
    assert ranking[0][2] == pytest.approx(2.6)


def test_azimuth_bins_follow_the_library_order() -> None:
    az_el = np.array([[a * 45.0, e] for a in range(8) for e in (0.0, 30.0)])
    assert azimuth_bins(az_el, 8).tolist() == [a for a in range(8) for _ in range(2)]


def _render_views(library: Any, model: int, views: list[int], pad: tuple[int, int]) -> list:
    """Masks of a library model at library poses, rendered into a larger, shifted canvas."""
    from cadnerf_core.mesh.renderer import render_silhouette_polygons

    mesh = library.mesh(library.models[model].id)
    size = library.spec.render_size
    out = []
    for v in views:
        mask = render_silhouette_polygons(mesh, library.K_render, library.poses[v], size, size)
        canvas = np.zeros((size + 2 * pad[1], size + 2 * pad[0]), bool)
        canvas[pad[1]:pad[1] + size, pad[0]:pad[0] + size] = mask
        out.append(canvas)
    return out


@pytest.mark.parametrize("solver", ["dp", "paper"])
def test_retrieval_of_a_library_model_at_library_poses(tiny_library: Any,
                                                     solver: Literal["dp", "paper"]) -> None:
    library = tiny_library
    model = next(i for i, m in enumerate(library.models) if m.category == "cuboid")
    n_el = len(library.spec.elevations)
    # A walk once around the object (the use the spread prior is made for).
    true_views = [a * n_el + (a % n_el) for a in (1, 3, 5, 7)]
    pad = (40, 10)  # off-centre in a bigger photo: the canonical crop undoes it
    masks = _render_views(library, model, true_views, pad)
    names = [f"p{i}.png" for i in range(len(masks))]
    result = retrieve(masks, names, library, RetrievalConfig(solver=solver), crop_size=96)
    assert result.model_id == library.models[model].id
    assert result.top_models[0]["model_id"] == result.model_id
    assert result.top_models[0]["votes"] == len(masks)
    for match, v in zip(result.matches, true_views, strict=True):
        assert not match.discarded and match.iou > 0.95
        # A cuboid looks the same from az, -az, 180 - az and 180 + az: any of them is right.
        true_az, true_el = library.az_el[v]
        same = {round(x % 360.0, 3) for x in (true_az, -true_az, 180 - true_az, 180 + true_az)}
        assert round(match.azimuth, 3) in same and match.elevation == true_el
        assert np.allclose(match.c2w, library.poses[match.view])
        # The photo's intrinsics: the library camera, shifted by the padding. Exact up to
        # the rounding of the silhouettes' bounding boxes to whole pixels.
        expected = library.K_render.copy()
        expected[:2, 2] += pad
        assert np.allclose(match.K_photo, expected, rtol=1e-3, atol=0.5)
        assert match.box.size == 96 and match.K_canon[0, 0] > 0
    data = result.to_json()
    assert json.loads(json.dumps(data))["model_id"] == result.model_id
    assert len(data["matches"]) == len(masks) and data["discarded"] == []


def test_retrieval_finds_the_exact_views_of_an_asymmetric_model(tiny_library: Any) -> None:
    library = tiny_library
    model = next(i for i, m in enumerate(library.models) if m.category == "chair")
    n_el = len(library.spec.elevations)
    # A walk around the object (every solver), and half a walk with uneven steps: exact for
    # the paper's solver and for the DP without its spread prior. (The default prior, made
    # for walks around the object, may spread a half walk; see RetrievalConfig.)
    walks: dict[tuple[int, ...], tuple[dict[str, Any], ...]] = {
        (1, 3, 5, 7): ({"solver": "dp"}, {"solver": "paper"}),
        (1, 2, 3, 5): ({"solver": "dp", "spread_weight": 0.0}, {"solver": "paper"})}
    for azimuths, configs in walks.items():
        true_views = [a * n_el + (a % n_el) for a in azimuths]
        masks = _render_views(library, model, true_views, (0, 0))
        for options in configs:
            result = retrieve(masks, ["a", "b", "c", "d"], library, RetrievalConfig(**options))
            assert result.model_id == library.models[model].id
            assert [m.view for m in result.matches] == true_views, options
            assert all(m.iou > 0.8 for m in result.matches)


def _walk(library: Any, category: str, azimuths: tuple[int, ...]
          ) -> tuple[list[int], list[np.ndarray]]:
    """The library views of a walk round the model of ``category`` (azimuth bins, elevation
    alternating) and its masks."""
    model = next(i for i, m in enumerate(library.models) if m.category == category)
    n_el = len(library.spec.elevations)
    views = [a * n_el + (a % n_el) for a in azimuths]
    return views, _render_views(library, model, views, (0, 0))


def test_a_given_walking_direction_is_honoured_by_both_solvers(tiny_library: Any) -> None:
    library = tiny_library
    # A clockwise walk (decreasing azimuth) around the asymmetric chair.
    true_views, masks = _walk(library, "chair", (7, 5, 3, 1))
    names = ["a", "b", "c", "d"]
    found = retrieve(masks, names, library, RetrievalConfig())
    assert [m.view for m in found.matches] == true_views and found.direction == -1
    # The chair's silhouettes tell the direction: a clear lead, no warning.
    assert found.direction_lead is not None and found.direction_lead > 0.1
    assert not found.direction_ambiguous
    # The paper's order is counter-clockwise: it misses this walk unless told.
    paper = retrieve(masks, names, library, RetrievalConfig(solver="paper"))
    assert [m.view for m in paper.matches] != true_views
    for solver in ("dp", "paper"):
        given = retrieve(masks, names, library, RetrievalConfig(solver=solver, walk="cw"))
        assert [m.view for m in given.matches] == true_views, solver
        assert given.direction == -1 and given.direction_lead is None
    # Told the wrong way, the DP obeys (and fits the walk worse).
    wrong = retrieve(masks, names, library, RetrievalConfig(walk="ccw"))
    assert wrong.direction == 1 and wrong.score < found.score
    assert json.loads(json.dumps(wrong.to_json()))["direction_lead"] is None


def test_a_walk_that_looks_alike_both_ways_is_flagged_as_a_guess(tiny_library: Any) -> None:
    library = tiny_library
    # A box looks the same from azimuth a and -a: walked either way, the masks are alike.
    _, masks = _walk(library, "cuboid", (1, 3, 5, 7))
    found = retrieve(masks, ["a", "b", "c", "d"], library, RetrievalConfig())
    assert found.direction_lead is not None and abs(found.direction_lead) < 1e-9
    assert found.direction_ambiguous and found.to_json()["direction_ambiguous"] is True
    # Given the direction, there is nothing to guess.
    given = retrieve(masks, ["a", "b", "c", "d"], library, RetrievalConfig(walk="ccw"))
    assert not given.direction_ambiguous and given.direction == 1


def test_an_ambiguous_walk_is_taken_counter_clockwise_unless_asked_for_the_best(
        tiny_library: Any) -> None:
    """Below the ambiguity margin the DP's lead is no evidence: the counter-clockwise walk
    (``ambiguous_walk`` "ccw") is assumed, the lead still reported; "best" keeps the lead's."""
    library = tiny_library
    # A clockwise walk round the asymmetric chair, with a margin no lead reaches.
    _, masks = _walk(library, "chair", (7, 5, 3, 1))
    names = ["a", "b", "c", "d"]
    sure = retrieve(masks, names, library, RetrievalConfig())
    assert sure.direction == -1 and not sure.direction_ambiguous
    assert sure.direction_lead is not None and sure.direction_lead > 0
    best = retrieve(masks, names, library,
                    RetrievalConfig(ambiguity_margin=100.0, ambiguous_walk="best"))
    assert best.direction_ambiguous and best.direction == -1
    assert [m.view for m in best.matches] == [m.view for m in sure.matches]
    assumed = retrieve(masks, names, library, RetrievalConfig(ambiguity_margin=100.0))
    ccw = retrieve(masks, names, library, RetrievalConfig(walk="ccw"))
    assert assumed.direction_ambiguous and assumed.direction == 1
    assert [m.view for m in assumed.matches] == [m.view for m in ccw.matches]
    assert assumed.model_id == ccw.model_id
    assert assumed.direction_lead == pytest.approx(sure.direction_lead)


def _match(index: int, focal: float, discarded: bool = False) -> Any:
    from cadnerf_core.cameras.conventions import orbit_pose
    from cadnerf_core.intake.crop import CropBox, crop_intrinsics
    from cadnerf_core.retrieval.result import PhotoMatch

    K_photo = np.array([[focal, 0.0, 140.0], [0.0, focal, 95.0], [0.0, 0.0, 1.0]])
    box = CropBox(40.0, 10.0, 150.0, 64)
    return PhotoMatch(index, f"p{index}", 0, 30.0 * index, 15.0, 0.9, discarded,
                      orbit_pose(30.0 * index, 15.0, 4.0), crop_intrinsics(K_photo, box), box,
                      K_photo)


def test_shared_focal_keeps_every_object_its_size() -> None:
    from cadnerf_core.cameras.conventions import project
    from cadnerf_core.intake.crop import crop_intrinsics
    from cadnerf_core.retrieval.cameras import share_focal

    # Focal lengths per pixel of the longer side: 1/3, 0.4, 0.25 (a photo of twice the
    # resolution); the discarded photo's wild estimate has no say in the median, 1/3, and
    # is moved by half at most (FOCAL_SCALE_LIMITS), 900 -> 450 instead of 100.
    matches = [_match(0, 100.0), _match(1, 120.0), _match(2, 150.0), _match(3, 900.0, True)]
    sizes = [(200, 300), (200, 300), (400, 600), (200, 300)]
    shared = share_focal(matches, sizes)
    assert [m.K_photo[0, 0] for m in shared] == pytest.approx([100.0, 100.0, 200.0, 450.0])
    for before, after in zip(matches, shared, strict=True):
        scale = after.K_photo[0, 0] / before.K_photo[0, 0]
        assert after.K_photo[1, 1] == pytest.approx(after.K_photo[0, 0])
        assert np.allclose(after.K_photo[:2, 2], before.K_photo[:2, 2])  # principal point
        assert np.allclose(after.c2w[:3, :3], before.c2w[:3, :3])  # rotation
        # Moved along its ray to the centre by the focal length's factor.
        assert np.linalg.norm(after.c2w[:3, 3]) == pytest.approx(4.0 * scale)
        assert np.allclose(after.K_canon, crop_intrinsics(after.K_photo, after.box))
        if not before.discarded:
            # Points on the plane through the object's centre facing the camera keep their
            # pixels: the object keeps its size and place in the photo.
            right, down = before.c2w[:3, 0], before.c2w[:3, 1]
            points = np.stack([0.3 * right, -0.5 * down, 0.2 * right + 0.4 * down])
            assert np.allclose(project(points, after.K_photo, after.c2w),
                               project(points, before.K_photo, before.c2w), atol=1e-6)
    assert share_focal(matches[:1], sizes[:1])[0] is matches[0]  # one photo: nothing to share


def test_a_photo_taken_from_farther_away_gets_a_farther_camera(tiny_library: Any) -> None:
    import cv2

    library = tiny_library
    views, masks = _walk(library, "chair", (1, 3, 5, 7))
    # Photo 2 from twice as far with the same camera: the chair at half its size.
    size = masks[2].shape[0]
    small = cv2.resize(masks[2].astype(np.uint8), (size // 2, size // 2),
                       interpolation=cv2.INTER_AREA) > 0
    masks[2] = np.zeros_like(masks[2])
    masks[2][size // 4:size // 4 + size // 2, size // 4:size // 4 + size // 2] = small
    names = ["a", "b", "c", "d"]
    shared = retrieve(masks, names, library, RetrievalConfig())
    own = retrieve(masks, names, library, RetrievalConfig(shared_focal=False))
    assert [m.view for m in shared.matches] == [m.view for m in own.matches] == views
    distances = [float(np.linalg.norm(m.c2w[:3, 3])) for m in shared.matches]
    focals = [m.K_photo[0, 0] for m in shared.matches]
    assert max(focals) == pytest.approx(min(focals))
    assert distances[2] / np.median(distances) == pytest.approx(2.0, rel=0.1)
    # Without it, the photo gets the library distance and half the focal length (a zoom).
    assert {round(float(np.linalg.norm(m.c2w[:3, 3])), 6) for m in own.matches} == {4.0}
    assert own.matches[2].K_photo[0, 0] / own.matches[0].K_photo[0, 0] == \
        pytest.approx(0.5, rel=0.1)


def test_a_known_focal_length_wins_over_the_matches(tiny_library: Any) -> None:
    library = tiny_library
    _, masks = _walk(library, "chair", (1, 3, 5, 7))
    names = ["a", "b", "c", "d"]
    estimated = retrieve(masks, names, library, RetrievalConfig())
    # One photo knows its focal length (EXIF): 1.5 times the estimate; the others do not.
    known = 1.5 * estimated.matches[0].K_photo[0, 0]
    told = retrieve(masks, names, library, RetrievalConfig(), focals=[None, known, None, None])
    assert [m.K_photo[0, 0] for m in told.matches] == pytest.approx([known] * 4)
    for before, after in zip(estimated.matches, told.matches, strict=True):
        # A longer lens sees the object at the same size from farther away.
        assert np.linalg.norm(after.c2w[:3, 3]) == pytest.approx(
            1.5 * np.linalg.norm(before.c2w[:3, 3]), rel=1e-6)


def _near_walk(library: Any, azimuths: tuple[int, ...]) -> tuple[list[int], list[np.ndarray],
                                                                  float]:
    """Masks of the chair seen from the near set's cameras (a wide lens, close up), with
    their focal length in pixels."""
    from cadnerf_core.mesh.renderer import render_silhouette_polygons

    near = library.near
    model = next(i for i, m in enumerate(library.models) if m.category == "chair")
    n_el = len(library.spec.elevations)
    views = [a * n_el + (a % n_el) for a in azimuths]
    mesh = library.mesh(library.models[model].id)
    size = near.spec.render_size
    masks = [render_silhouette_polygons(mesh, near.K_render, near.poses[v], size, size)
             for v in views]
    return views, masks, float(near.K_render[0, 0])


def test_a_known_focal_length_chooses_the_silhouettes_of_the_photos_perspective(
        tiny_library: Any) -> None:
    library = tiny_library
    views, masks, focal = _near_walk(library, (1, 3, 5, 7))
    names = ["a", "b", "c", "d"]
    told = retrieve(masks, names, library, RetrievalConfig(), focals=[focal] * 4)
    assert told.perspective == "near"
    assert [m.view for m in told.matches] == views
    assert all(m.iou > 0.9 for m in told.matches)
    # The cameras stand where the photos were taken: the near set's distance, their focal.
    for m in told.matches:
        assert np.linalg.norm(m.c2w[:3, 3]) == pytest.approx(library.spec.near_distance,
                                                             rel=1e-6)
        assert m.K_photo[0, 0] == pytest.approx(focal)
    assert json.loads(json.dumps(told.to_json()))["perspective"] == "near"
    # Without a focal length the far set is matched; its best IoU is lower.
    blind = retrieve(masks, names, library, RetrievalConfig())
    assert blind.perspective == "far"
    assert np.mean([m.iou for m in blind.matches]) < np.mean([m.iou for m in told.matches])
    # The far set's own photos with their focal length keep the far set.
    far_views, far_masks = _walk(library, "chair", (1, 3, 5, 7))
    far = retrieve(far_masks, names, library, RetrievalConfig(),
                   focals=[float(library.K_render[0, 0])] * 4)
    assert far.perspective == "far" and [m.view for m in far.matches] == far_views
    # One photo's focal length is enough to choose.
    one = retrieve(masks, names, library, RetrievalConfig(), focals=[None, focal, None, None])
    assert one.perspective == "near" and [m.view for m in one.matches] == views
    # Asked for, a set is used whatever the focal length says.
    forced = retrieve(far_masks, names, library, RetrievalConfig(perspective="near"))
    assert forced.perspective == "near"


def test_asking_for_a_near_set_the_library_lacks_says_how_to_get_one(tiny_library: Any) -> None:
    import dataclasses

    from cadnerf_core.errors import LibraryError
    from cadnerf_core.library.format import Library

    library = tiny_library
    old = Library(library.root, dataclasses.replace(library.spec, near_distance=None),
                  library.models, library._packed, library.boxes)
    _, masks = _walk(library, "chair", (1, 3, 5, 7))
    with pytest.raises(LibraryError, match="no 'near' silhouette set.*library build"):
        retrieve(masks, ["a", "b", "c", "d"], old, RetrievalConfig(perspective="near"))
    result = retrieve(masks, ["a", "b", "c", "d"], old, RetrievalConfig(), focals=[100.0] * 4)
    assert result.perspective == "far"


@pytest.mark.parametrize("solver", ["dp", "paper"])
def test_an_excluded_model_is_never_retrieved(tiny_library: Any,
                                              solver: Literal["dp", "paper"]) -> None:
    library = tiny_library
    model = next(i for i, m in enumerate(library.models) if m.category == "cuboid")
    n_el = len(library.spec.elevations)
    masks = _render_views(library, model, [a * n_el for a in (1, 3, 5, 7)], (0, 0))
    names = [f"p{i}.png" for i in range(len(masks))]
    own = library.models[model].id
    assert retrieve(masks, names, library, RetrievalConfig(solver=solver)).model_id == own
    others = [m.id for m in library.models if m.id != own]
    for kept in others:  # each other model in turn the only one left, then both
        excluded = tuple(m.id for m in library.models if m.id != kept)
        result = retrieve(masks, names, library,
                          RetrievalConfig(solver=solver, exclude_models=excluded))
        assert result.model_id == kept
        assert {t["model_id"] for t in result.top_models} == {kept}
        assert np.isfinite([m.iou for m in result.matches]).all()
    result = retrieve(masks, names, library, RetrievalConfig(solver=solver,
                                                             exclude_models=(own,)))
    assert result.model_id in others
    assert own not in {t["model_id"] for t in result.top_models}


def test_excluding_an_unknown_or_every_model_is_a_clear_error(tiny_library: Any) -> None:
    from cadnerf_core.errors import InputError

    masks = [np.pad(np.ones((20, 20), bool), 10)] * 3
    names = ["a.png", "b.png", "c.png"]
    with pytest.raises(InputError, match="no model 'no_such_model' in the library") as err:
        retrieve(masks, names, tiny_library, RetrievalConfig(exclude_models=("no_such_model",)))
    assert tiny_library.models[0].id in str(err.value)  # the message lists the choices
    every = tuple(m.id for m in tiny_library.models)
    with pytest.raises(InputError, match="every library model is excluded"):
        retrieve(masks, names, tiny_library, RetrievalConfig(exclude_models=every))


def test_exclude_models_rejects_blanks_and_repeats() -> None:
    from pydantic import ValidationError

    assert RetrievalConfig(exclude_models=("a", "b")).exclude_models == ("a", "b")
    with pytest.raises(ValidationError, match="twice"):
        RetrievalConfig(exclude_models=("a", "a"))
    with pytest.raises(ValidationError, match="empty"):
        RetrievalConfig(exclude_models=(" ",))


def test_hypotheses_are_the_next_best_distinct_walks(tiny_library: Any) -> None:
    library = tiny_library
    model = next(i for i, m in enumerate(library.models) if m.id == "chair_wood")
    n_el = len(library.spec.elevations)
    masks = _render_views(library, model, [a * n_el for a in (1, 3, 5, 7)], (0, 0))
    names = [f"p{i}.png" for i in range(len(masks))]
    assert retrieve(masks, names, library, RetrievalConfig(hypotheses=1)).alternatives == []
    # No focal length known: the near set's best walk comes first, then the far set's next.
    result = retrieve(masks, names, library, RetrievalConfig(hypotheses=4))
    assert result.perspective == "far" and len(result.alternatives) == 3
    assert [h.perspective for h in result.alternatives] == ["near", "far", "far"]
    seen = [(h.model_id, h.direction) for h in (result, *result.alternatives[1:])]
    assert len(set(seen)) == 3
    scores = [h.score for h in result.alternatives[1:]]
    assert scores == sorted(scores, reverse=True)
    assert all(len(h.matches) == len(masks) for h in result.alternatives)
    assert "hypotheses" not in result.to_json()
    told = retrieve(masks, names, library, RetrievalConfig(hypotheses=3, walk="cw",
                                                           perspective="far"))
    assert {h.direction for h in (told, *told.alternatives)} == {-1}
    assert {h.perspective for h in told.alternatives} == {"far"}


def _walk_table(n_photos: int, n_models: int, n_az: int, rng: np.random.Generator
                ) -> np.ndarray:
    """[P, M, V] IoU with one elevation per azimuth: model ``M - 1`` fits the photos evenly
    spread round the turn at 0.8, each other model m fits photo m alone at 0.9 (its vote) and
    the rest at random below 0.5."""
    iou = rng.uniform(0.0, 0.5, (n_photos, n_models, n_az)).astype(np.float32)
    for p in range(n_photos):
        iou[p, n_models - 1, p * n_az // n_photos] = 0.8
        if p < n_models - 1:
            iou[p, p, int(rng.integers(n_az))] = 0.9
    return iou


def test_the_best_walk_wins_though_no_photo_voted_for_its_model() -> None:
    from cadnerf_core.retrieval.walks import choose_walk

    n_photos, n_models, n_az = 6, 7, 12
    iou = _walk_table(n_photos, n_models, n_az, np.random.default_rng(0))
    voted, ranking = vote_models(iou)
    assert dict((m, v) for m, v, _ in ranking)[n_models - 1] == 0  # no vote for the walker
    az_index = np.arange(n_az)
    every = RetrievalConfig(walk_models=0)
    m, walk = choose_walk(iou, voted, ranking, az_index, n_az, every, 0.0)
    assert m == n_models - 1 and list(walk.views) == [p * 2 for p in range(n_photos)]
    five = RetrievalConfig(walk_models=5)
    m5, _ = choose_walk(iou, voted, ranking, az_index, n_az, five, 0.0)
    assert m5 != n_models - 1 and m5 in [e[0] for e in ranking[:5]]


def test_pruning_by_the_walk_bound_changes_no_choice(monkeypatch: pytest.MonkeyPatch) -> None:
    from cadnerf_core.retrieval import walks as module

    rng = np.random.default_rng(1)
    for trial, solver in enumerate(["dp"] * 6 + ["paper"] * 2):
        config = RetrievalConfig(hypotheses=4, solver=solver)  # type: ignore[arg-type]
        n_photos = 4 + trial % 6
        iou = rng.uniform(0.0, 1.0, (n_photos, 9, 16)).astype(np.float32) ** 2
        voted, ranking = vote_models(iou)
        az_index = np.arange(16)
        for entry in ranking:  # the bound holds for every model, either way round
            for walk in ("ccw", "cw"):
                found = module.solve_poses(iou[:, entry[0]], az_index, 16,
                                           config.model_copy(update={"walk": walk}))
                assert found.score <= module.walk_bound(entry, n_photos, config)
        pruned = module.choose_walk(iou, voted, ranking, az_index, 16, config, 0.0)
        chosen = (pruned[0], pruned[1].direction)
        alternatives = module.alternatives(iou, ranking, az_index, 16, config, 0.0,
                                            chosen)
        with monkeypatch.context() as patched:
            patched.setattr(module, "walk_bound", lambda *_: float("inf"))
            full = module.choose_walk(iou, voted, ranking, az_index, 16, config, 0.0)
            every = module.alternatives(iou, ranking, az_index, 16, config, 0.0,
                                         chosen)
        assert pruned[0] == full[0] and pruned[1].score == full[1].score
        assert [(m, w.direction, w.score) for m, w in alternatives] == \
            [(m, w.direction, w.score) for m, w in every]
        assert len(alternatives) == 3
