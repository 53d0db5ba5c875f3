"""The unseen-objects benchmark's plan: shards that run side by side cover every job once, and
the section built from their rows says which jobs did not run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks import bench_unseen, harness


@pytest.fixture
def meshes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> list[str]:
    names = ["armchair", "CesiumMilkTruck", "ycb_mug", "Duck"]
    for name in names:
        (tmp_path / "meshes" / name).mkdir(parents=True)
    monkeypatch.setattr(harness, "MESHES", tmp_path / "meshes")
    monkeypatch.setattr(bench_unseen, "MESHES", tmp_path / "meshes")
    return names


def test_shards_cover_every_job_once(meshes: list[str]) -> None:
    plan = bench_unseen.make_plan(False)
    jobs = [job[:3] for job in bench_unseen.job_list(plan)]
    assert len(jobs) == len(set(jobs))
    assert {(m, f, "leave-out") for m in meshes for f in bench_unseen.FOVS} <= set(jobs)
    exif = [job for job in bench_unseen.job_list(plan) if job[2] == bench_unseen.EXIF_VARIANT]
    assert exif and all(job[5] for job in exif)  # its photos carry their focal length
    assert not any(job[5] for job in bench_unseen.job_list(plan) if job not in exif)
    shards = [job for i in range(5)
              for job in bench_unseen.job_list(plan)[i::5]]
    assert sorted(job[:3] for job in shards) == sorted(jobs)


def test_section_from_rows_lists_jobs_not_run(meshes: list[str], tmp_path: Path) -> None:
    plan = bench_unseen.make_plan(False, variants=["leave-out"])
    jobs = bench_unseen.job_list(plan)
    assert len(jobs) == len(meshes) * len(bench_unseen.FOVS)
    rows = [{"mesh": m, "fov": f, "variant": v, "model": "mug", "psnr": 20.0 + k,
             "rot": 4.0 + k, "r_rot": 10.0, "focal_err": 5.0, "r_focal_err": 5.0,
             "job_s": 60.0, "hypotheses": 3, "fit_s": 1.0, "switched": False}
            for k, (m, f, v, *_) in enumerate(jobs[:-1])]
    files = []
    for i in range(2):
        file = tmp_path / f"rows{i}.jsonl"
        file.write_text("".join(json.dumps(r) + "\n" for r in rows[i::2]))
        files.append(file)
    text = bench_unseen.from_rows(files, False, None, ["leave-out"], "a GPU", 123.0, 2)
    missing = jobs[-1]
    assert f"- {missing[0]} leave-out {missing[1]:g} deg: not run" in text
    assert "--device cuda --shard I/2" in text and "(123 s, a GPU)" in text
    # the summary's "all" row: mean PSNR and median rotation over the jobs that ran
    expected_psnr = sum(r["psnr"] for r in rows) / len(rows)
    assert f"| leave-out | all | {len(rows)} | {expected_psnr:.2f} |" in text


def test_fovs_restrict_every_row_and_name_themselves(meshes: list[str]) -> None:
    plan = bench_unseen.make_plan(False, variants=["with look-alike"], fovs=[40.0])
    jobs = bench_unseen.job_list(plan)
    assert sorted(job[:3] for job in jobs) == sorted((m, 40.0, "with look-alike")
                                                     for m in meshes)
    text = bench_unseen.section(plan, [], 1.0, False, None)
    assert '--variants "with look-alike" --fovs 40`' in text
    assert "fields of view 40 deg" in text
    assert "--fovs" not in bench_unseen.section(bench_unseen.make_plan(False), [], 1.0, False,
                                                None)
    with pytest.raises(SystemExit):
        bench_unseen.main(["--fovs", "45"])


def test_views_name_themselves_and_keep_rows_apart(meshes: list[str], tmp_path: Path) -> None:
    plan = bench_unseen.make_plan(False, variants=["leave-out"], fovs=[55.0], views=9)
    text = bench_unseen.section(plan, [], 1.0, False, None)
    assert "--fovs 55 --views 9`" in text and "Walks of 9 views" in text
    assert "; 9 views)" in text.splitlines()[0]
    assert "--views" not in bench_unseen.section(bench_unseen.make_plan(False), [], 1.0, False,
                                                 None)
    # a rows file holding walks of 6 and of 9 photos: each section takes only its own
    row = {"mesh": meshes[0], "fov": 55.0, "variant": "leave-out", "model": "mug",
           "psnr": 20.0, "rot": 4.0, "r_rot": 10.0, "focal_err": 5.0, "r_focal_err": 5.0,
           "job_s": 60.0, "hypotheses": 3, "fit_s": 1.0, "switched": False}
    file = tmp_path / "rows.jsonl"
    file.write_text(json.dumps({**row, "views": 9, "psnr": 25.0}) + "\n"
                    + json.dumps(row) + "\n")  # rows written before views were recorded: 6
    nine = bench_unseen.from_rows([file], False, None, ["leave-out"], "cpu", 1.0, 1,
                                  fovs=[55.0], views=9)
    six = bench_unseen.from_rows([file], False, None, ["leave-out"], "cpu", 1.0, 1,
                                 fovs=[55.0])
    assert f"| {meshes[0]} | 55 | leave-out | mug | 25.00 |" in nine
    assert f"| {meshes[0]} | 55 | leave-out | mug | 20.00 |" in six
    with pytest.raises(SystemExit):
        bench_unseen.main(["--views", "2"])


def test_rows_without_start_records_leave_those_columns_empty(meshes: list[str]) -> None:
    rows = [{"mesh": m, "fov": 40.0, "variant": "leave-out", "psnr": 20.0, "rot": 5.0,
             "focal_err": 1.0, "job_s": 60.0} for m in meshes]
    summary = bench_unseen.summary_rows(rows)
    assert all(s["switched"] is None and s["fit_s"] is None for s in summary)
    rows[0].update(switched=True, fit_s=1.0)
    assert [s["switched"] for s in bench_unseen.summary_rows(rows[:1])] == [1, 1]


def test_jobs_of_walks_with_other_photo_counts_get_folders_of_their_own(
        meshes: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from cadnerf_core.evaluation import evaluate

    seen: list[tuple[int, Path]] = []

    def fake_walk(name: str, fov: float, work: Path, views: int = 6,
                  direction: int | None = None) -> Path:
        return work / name / (f"fov{fov:g}" if views == 6 else f"fov{fov:g}_{views}views")

    def refuse(walk: Path, views: int, *args: object, job_dir: Path, **kwargs: object) -> None:
        seen.append((views, job_dir))
        raise RuntimeError("not trained here")

    monkeypatch.setattr(bench_unseen, "fov_walk", fake_walk)
    monkeypatch.setattr(evaluate, "evaluate_dataset", refuse)
    for views in (6, 9):
        plan = bench_unseen.make_plan(False, variants=["leave-out"], fovs=[40.0], views=views)
        row = bench_unseen.run_job(meshes[0], 40.0, "leave-out", {}, "leave-out", plan, None,
                                   tmp_path)
        assert row["views"] == views and "not trained here" in row["error"]
    assert [v for v, _ in seen] == [6, 9]
    assert seen[0][1] != seen[1][1] and seen[0][1].parent == seen[1][1].parent


def test_a_queue_run_resumes_from_its_rows_file(meshes: list[str], tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    row = {"mesh": meshes[0], "fov": 40.0, "variant": "leave-out", "views": 9,
           "model": "mug", "psnr": 23.0, "rot": 4.0, "r_rot": 10.0, "focal_err": 5.0,
           "r_focal_err": 5.0, "job_s": 60.0, "hypotheses": 3, "fit_s": 1.0,
           "switched": False}
    failed = {**row, "mesh": meshes[1], "error": "RuntimeError: out of memory"}
    file = tmp_path / "rows.jsonl"
    file.write_text(json.dumps(row) + "\n" + json.dumps(failed) + "\n")
    assert list(bench_unseen.rows_done(file)) == [(meshes[0], 40.0, "leave-out", 9)]
    assert bench_unseen.rows_done(tmp_path / "absent.jsonl") == {}

    queued: list[tuple[int, str]] = []

    def fake_queue(jobs: list, work: Path, device: str, workers: int,
                   rows_file: Path | None = None) -> list[dict]:
        assert workers == 2 and rows_file == file
        queued.extend((plan.views, job[0]) for plan, job in jobs)
        return []

    monkeypatch.setattr(bench_unseen, "run_queue", fake_queue)
    monkeypatch.setattr(bench_unseen, "WORK_DIR", tmp_path / "work")
    text = bench_unseen.run(False, variants=["leave-out"], fovs=[40.0], views=[6, 9],
                            workers=2, rows_file=file)
    # the job that ran is not queued again; the one that failed is, and so is every 6-view job
    assert sorted(queued) == sorted([(6, m) for m in meshes] + [(9, m) for m in meshes[1:]])
    nine = text[text.index("; 9 views)"):]
    assert f"| {meshes[0]} | 40 | leave-out | mug | 23.00 |" in nine
    assert "--views 9 --workers 2`" in nine and "one run for 6 and 9 views" in nine
    with pytest.raises(SystemExit):
        bench_unseen.main(["--workers", "0"])


def test_clockwise_rows_walk_the_other_way_in_full_runs_only(
        meshes: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from cadnerf_core.evaluation import evaluate

    full = bench_unseen.job_list(bench_unseen.make_plan(False))
    assert {(m, f) for m, f, v, *_ in full if v == bench_unseen.CW_VARIANT} == {
        (m, f) for m in meshes for f in bench_unseen.FOVS}
    assert all(job[4] == "leave-out" for job in full if job[2] == bench_unseen.CW_VARIANT)
    quick = bench_unseen.job_list(bench_unseen.make_plan(True))
    assert quick and not any(job[2] == bench_unseen.CW_VARIANT for job in quick)
    asked = bench_unseen.job_list(bench_unseen.make_plan(True, variants=["clockwise"]))
    assert asked and all(job[2] == bench_unseen.CW_VARIANT for job in asked)

    walked: list[int | None] = []

    def fake_walk(name: str, fov: float, work: Path, views: int = 6,
                  direction: int | None = None) -> Path:
        walked.append(direction)
        return work / name / f"fov{fov:g}"

    def refuse(*args: object, **kwargs: object) -> None:
        raise RuntimeError("not trained here")

    monkeypatch.setattr(bench_unseen, "fov_walk", fake_walk)
    monkeypatch.setattr(evaluate, "evaluate_dataset", refuse)
    plan = bench_unseen.make_plan(False, fovs=[40.0])
    for variant in ("leave-out", bench_unseen.CW_VARIANT):
        bench_unseen.run_job(meshes[0], 40.0, variant, {}, "leave-out", plan, None, tmp_path)
    assert walked == [None, -1]  # the seed's way (counter-clockwise for seed 0), then clockwise


def test_summary_puts_both_walking_directions_together() -> None:
    def row(variant: str, fov: float, psnr: float, rot: float) -> dict[str, object]:
        return {"mesh": "mug", "fov": fov, "variant": variant, "psnr": psnr, "rot": rot,
                "focal_err": 10.0, "job_s": 100.0}

    rows = [row("leave-out", 40.0, 24.0, 2.0), row("leave-out", 70.0, 22.0, 4.0),
            row("clockwise", 40.0, 14.0, 170.0), row("clockwise", 70.0, 20.0, 6.0)]
    both = {s["fov"]: s for s in bench_unseen.summary_rows(rows)
            if s["variant"] == bench_unseen.BOTH_WAYS}
    assert both["all"]["jobs"] == 4 and both["all"]["psnr"] == pytest.approx(20.0)
    assert both["all"]["rot"] == pytest.approx(5.0)  # median of 2, 4, 6, 170
    assert both["40"]["base_psnr"] == pytest.approx(24.0)  # base: the counter-clockwise walk
    assert not any(s["variant"] == bench_unseen.BOTH_WAYS
                   for s in bench_unseen.summary_rows(rows[:2]))


def test_a_whole_run_both_ways_records_the_readme_figures(
        meshes: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from benchmarks import results

    monkeypatch.setattr(results, "RESULTS", tmp_path / "results.json")
    plan = bench_unseen.make_plan(False, variants=["leave-out", "clockwise"])
    rows = [{"mesh": m, "fov": f, "variant": v, "psnr": 20.0 + i % 3, "rot": 5.0 + i % 5,
             "focal_err": 1.0, "job_s": 100.0}
            for i, (m, f, v, *_) in enumerate(bench_unseen.job_list(plan))]
    failed = [*rows[:-1], {**rows[-1], "error": "RuntimeError: out of memory"}]
    bench_unseen.record_headline(plan, failed, "cmd", "2 CPU cores")
    assert results.read_results() == {}  # a failed job: not the whole benchmark
    bench_unseen.record_headline(plan, rows, "cmd", "2 CPU cores")
    found = results.read_results()
    assert found["unseen_psnr"].value == pytest.approx(
        sum(r["psnr"] for r in rows) / len(rows))
    assert found["unseen_rotation"].conditions == f"leave-out, {len(rows)} jobs, 2 CPU cores"
    assert f"{len(meshes)} unseen meshes" in found["unseen_psnr"].quantity
