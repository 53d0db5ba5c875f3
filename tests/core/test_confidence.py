"""How each photo's camera was placed (``cameras.confidence``) and the warning that names the
photos whose cameras rest on their outlines alone."""

from __future__ import annotations

from typing import Any

from cadnerf_core.cameras.confidence import MAPPED_CONFIDENCE, camera_placements
from cadnerf_core.cameras.conventions import orbit_pose
from cadnerf_core.job_warnings import job_warnings, outlines_alone_warning


def _match(index: int, moved_deg: float | None = None, iou: float = 0.9,
           discarded: bool = False) -> dict[str, Any]:
    match: dict[str, Any] = {"index": index, "iou": iou, "discarded": discarded,
                             "c2w": orbit_pose(40.0 * index, 20.0, 4.0).tolist()}
    if moved_deg is not None:
        match["c2w_retrieved"] = orbit_pose(40.0 * index + moved_deg, 20.0, 4.0).tolist()
    return match


def test_each_kept_photo_says_how_its_camera_was_placed() -> None:
    retrieval = {"matches": [_match(0, 1.0), _match(1, 2.0), _match(2, 3.0), _match(3, 25.0),
                             _match(4, iou=0.8), _match(5, discarded=True)],
                 "fusion": {"photos": [0, 1, 2, 3], "mapped": [0, 1]}}
    placed = camera_placements(retrieval)
    assert [p.index for p in placed] == [0, 1, 2, 3, 4]
    assert [p.placed for p in placed] == ["matches", "matches", "both", "both", "silhouettes"]
    assert placed[0].confidence == MAPPED_CONFIDENCE
    # A fused camera that stayed near its outline's is surer than one the pairs moved far.
    assert placed[2].confidence > placed[3].confidence > placed[4].confidence
    assert min(p.confidence for p in placed) >= 0.0 and max(p.confidence for p in placed) <= 1.0
    started = camera_placements({"matches": retrieval["matches"][:3],
                                 "fusion": {"start": "mapper", "photos": [0, 1, 2]}})
    assert [p.placed for p in started] == ["matches"] * 3
    alone = camera_placements({"matches": retrieval["matches"][:3]})
    assert [p.placed for p in alone] == ["silhouettes"] * 3


def test_a_job_whose_photos_are_placed_apart_names_the_ones_to_retake() -> None:
    names = ["a.jpg", "b.jpg", "c.jpg", "d.jpg"]
    retrieval = {"focal_known": True, "order": [0, 1, 2, 3],
                 "matches": [_match(0, 1.0), _match(1, 2.0), _match(2, 1.0), _match(3)],
                 "fusion": {"photos": [0, 1, 2]}}
    assert job_warnings(retrieval, names) == [outlines_alone_warning(["d.jpg"])]
    everyone = {**retrieval, "fusion": {"photos": [0, 1, 2, 3]}}
    assert job_warnings(everyone, names) == []
    assert outlines_alone_warning(["d.jpg"]).startswith("The cameras of d.jpg rest on")
