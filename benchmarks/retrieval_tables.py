"""The retrieval benchmark's markdown tables and summaries of the synthetic and phone walks
(``benchmarks.bench_retrieval``)."""

from __future__ import annotations

import statistics

from benchmarks.retrieval_walks import PHONE_VARIANTS, VARIANTS, PhoneResult, SetResult


def synthetic_table(results: list[SetResult]) -> list[str]:
    """Markdown table rows of the synthetic walks, with a summary line."""
    keys = list(VARIANTS)
    lines = ["| mesh | views | dir | model, ours (votes) | mean IoU | dir found | lead | "
             + " | ".join(f"rot. err. {VARIANTS[k][0]}" for k in keys)
             + " | discarded ours / Alg. 1 |", "|---" * (8 + len(keys)) + "|"]
    for r in results:
        found = f"{r.directions['dp']:+d}{' (guess)' if r.ambiguous else ''}"
        lines.append(f"| {r.mesh} | {r.views} | {r.direction:+d} | {r.model} | "
                     f"{r.mean_iou:.2f} | {found} | {r.lead:.3f} | "
                     + " | ".join(f"{r.errors[k]:.1f}" for k in keys)
                     + f" | {r.dropped['dp']} / {r.dropped['paper']} |")
    errors = {k: [r.errors[k] for r in results] for k in keys}
    summary = "; ".join(f"{VARIANTS[k][0]} {statistics.median(errors[k]):.1f} deg "
                        f"({sum(e < 15 for e in errors[k])} sets under 15 deg)" for k in keys)
    worse = [f"{r.mesh} {r.views} {r.direction:+d} ({r.errors['dp']:.1f} vs "
             f"{r.errors['paper']:.1f}{', a guess' if r.ambiguous else ''})" for r in results
             if r.errors["dp"] > r.errors["paper"] + 1e-6]
    like = [f"{r.mesh} {r.views} {r.direction:+d} ({r.dp_on_paper_kept:.1f} vs "
            f"{r.errors['paper']:.1f})" for r in results
            if r.dp_on_paper_kept > r.errors["paper"] + 1e-6]
    right = sum(r.directions["dp"] == r.direction for r in results)
    guessed = [r for r in results if r.ambiguous]
    wrong_guess = sum(r.directions["dp"] != r.direction for r in guessed)
    wrong_sure = sum(r.directions["dp"] != r.direction for r in results if not r.ambiguous)
    worse_given = [f"{r.mesh} {r.views} {r.direction:+d} ({r.errors['walk']:.1f} vs "
                   f"{r.errors['paper_walk']:.1f})" for r in results
                   if r.errors["walk"] > r.errors["paper_walk"] + 1e-6]
    lines += ["", f"Median over the {len(results)} sets of the per-set median rotation error: "
              f"{summary}. Walking direction right (ours): {right} of {len(results)}. Sets "
              f"where ours is worse than Algorithm 1: {len(worse)}"
              f"{': ' + ', '.join(worse) if worse else ''}. Like for like (ours over the "
              f"photos Algorithm 1 kept, where it discarded some): worse on {len(like)}"
              f"{': ' + ', '.join(like) if like else ''}. Direction flagged as a guess "
              f"(``direction_ambiguous``): {len(guessed)} sets, wrong on {wrong_guess}; "
              f"wrong on {wrong_sure} of the {len(results) - len(guessed)} not flagged. With "
              f"the walking direction given to both solvers, ours is worse than Algorithm 1 "
              f"on {len(worse_given)}{': ' + ', '.join(worse_given) if worse_given else ''}.",
              "", *mesh_table(results)]
    return lines


def phone_summary(results: list[PhoneResult]) -> str:
    """One line: each variant's median error over the walks, and the sets ours chose."""
    summary = "; ".join(
        f"{label} {statistics.median(r.errors[k] for r in results):.1f} deg "
        f"({sum(r.errors[k] < 15 for r in results)} under 15, "
        f"{sum(r.errors[k] > 90 for r in results)} over 90)"
        for k, label in PHONE_VARIANTS.items())
    near = sum(r.chosen == "near" for r in results)
    return (f"At {results[0].fov:g} deg, median over the {len(results)} walks: {summary}. "
            f"Ours chose the near set on {near} of {len(results)}.")


def phone_table(results: list[PhoneResult]) -> list[str]:
    """Markdown table of the walks at one field of view."""
    keys = list(PHONE_VARIANTS)
    lines = ["| mesh | views | dir | set chosen | "
             + " | ".join(f"rot. err. {PHONE_VARIANTS[k]}" for k in keys) + " |",
             "|---" * (4 + len(keys)) + "|"]
    for r in results:
        lines.append(f"| {r.mesh} | {r.views} | {r.direction:+d} | {r.chosen} | "
                     + " | ".join(f"{r.errors[k]:.1f}" for k in keys) + " |")
    return lines


def mesh_table(results: list[SetResult]) -> list[str]:
    """Markdown table: per mesh, the median over its walks of each variant's error."""
    keys = list(VARIANTS)
    lines = ["| mesh (median of its walks) | " + " | ".join(VARIANTS[k][0] for k in keys)
             + " |", "|---" * (1 + len(keys)) + "|"]
    for mesh in sorted({r.mesh for r in results}):
        mine = [r for r in results if r.mesh == mesh]
        lines.append(f"| {mesh} | " + " | ".join(
            f"{statistics.median(r.errors[k] for r in mine):.1f}" for k in keys) + " |")
    return lines
