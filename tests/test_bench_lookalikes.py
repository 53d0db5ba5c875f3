"""The leave-out protocol's list: every look-alike is a shipped model, every object listed."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmarks.lookalikes import LOOKALIKES, exclude_overrides, excluded
from library_data.catalog import MODELS

EVAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "eval"


def test_every_lookalike_is_a_shipped_model_with_a_reason() -> None:
    shipped = {m.id for m in MODELS}
    for name, models in LOOKALIKES.items():
        for model_id, reason in models.items():
            assert model_id in shipped, f"{name}: {model_id} is not in the library"
            assert reason.strip(), f"{name}: {model_id} has no reason"


def test_protocols_exclude_the_lookalikes_or_nothing() -> None:
    assert excluded("Duck") == ("duck_toy",)
    assert excluded("Duck", "with look-alike") == ()
    assert exclude_overrides("spot") == {"retrieval.exclude_models": ["cow_toy"]}
    assert exclude_overrides("ycb_mug") == {}
    with pytest.raises(KeyError, match="add one"):
        excluded("no_such_object")


@pytest.mark.skipif(not (EVAL / "meshes").is_dir(), reason="../shared/eval is absent")
def test_every_evaluation_object_has_an_entry() -> None:
    folders = [*(EVAL / "meshes").iterdir(), *(EVAL / "photos").iterdir()]
    missing = [p.name for p in folders if p.is_dir() and p.name not in LOOKALIKES]
    assert not missing, f"add these to benchmarks.lookalikes.LOOKALIKES: {missing}"
