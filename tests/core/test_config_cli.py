"""`cadnerf config`: the settings a client may send as JSON Schema and as the guide's reference;
`--set` refusing anything else by name."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
from typer.testing import CliRunner

from cadnerf_cli.main import app
from cadnerf_core.config_client import (
    MAX_CLIENT_SETTINGS,
    SETTINGS_END,
    SETTINGS_START,
    schema_leaves,
    settings_markdown,
    with_settings_reference,
)

GUIDE = Path(__file__).resolve().parents[2] / "docs" / "guide.md"


def test_schema_is_valid_json_schema_of_at_most_30_documented_settings() -> None:
    result = CliRunner().invoke(app, ["config", "--schema"])
    assert result.exit_code == 0, result.output
    schema = json.loads(result.stdout)
    jsonschema.Draft202012Validator.check_schema(schema)
    leaves = schema_leaves(schema)
    assert 0 < len(leaves) <= MAX_CLIENT_SETTINGS == 30
    assert all(prop.get("description") for prop in leaves.values()), leaves
    validator = jsonschema.Draft202012Validator(schema)
    assert validator.is_valid({"phase2.steps": 300} | {"retrieval": {"walk": "cw"}}) is False
    assert validator.is_valid({"phase2": {"steps": 300}, "retrieval": {"walk": "cw",
                                                                       "focal_35mm": 26}})
    assert not validator.is_valid({"retrieval": {"hypotheses": 3}})
    assert not validator.is_valid({"export": {"orbit_size": 4096}})


def test_the_guide_holds_the_generated_reference() -> None:
    """docs/guide.md's settings table is what `cadnerf config --markdown` prints (regenerate
    with `cadnerf config --write docs/guide.md`)."""
    text = GUIDE.read_text(encoding="utf-8")
    assert with_settings_reference(text, settings_markdown()) == text
    committed = text.split(SETTINGS_START, 1)[1].split(SETTINGS_END, 1)[0]
    printed = CliRunner().invoke(app, ["config", "--markdown"]).stdout
    assert committed.strip() == printed.strip()
    for path in schema_leaves(json.loads(CliRunner().invoke(app, ["config", "--schema"]).stdout)):
        assert f"| `{path}` |" in committed


def test_write_puts_the_reference_between_the_markers(tmp_path: Path) -> None:
    doc = tmp_path / "guide.md"
    doc.write_text(f"# Guide\n\n{SETTINGS_START}\nstale\n{SETTINGS_END}\n\nafter\n")
    assert CliRunner().invoke(app, ["config", "--write", str(doc)]).exit_code == 0
    text = doc.read_text()
    assert "stale" not in text and text.endswith(f"{SETTINGS_END}\n\nafter\n")
    assert "| `retrieval.walk` |" in text
    again = CliRunner().invoke(app, ["config", "--write", str(doc)])
    assert "already up to date" in again.stdout and doc.read_text() == text
    doc.write_text("no markers\n")
    assert CliRunner().invoke(app, ["config", "--write", str(doc)]).exit_code == 2


def test_set_refuses_a_setting_a_client_may_not_change(tmp_path: Path) -> None:
    photo = tmp_path / "a.png"
    photo.write_bytes(b"not read: the config is checked first")
    for key, value in (("retrieval.hypotheses", "3"), ("phase2.prior_weight", "1")):
        result = CliRunner().invoke(app, ["reconstruct", str(photo), str(photo), str(photo),
                                          "--out", str(tmp_path / "out"), "--set",
                                          f"{key}={value}"])
        assert result.exit_code == 2
        assert f"--set {key}: not a setting you may change" in result.output, result.output
        assert "cadnerf config --schema" in result.output
    bad = CliRunner().invoke(app, ["reconstruct", str(photo), "--out", str(tmp_path / "o"),
                                   "--set", "phase2.steps=-1"])
    assert bad.exit_code == 2 and "--set phase2.steps" in bad.output
    assert "allowed: 0 <= phase2.steps <= 50000" in bad.output
    assert not (tmp_path / "out").exists() and not (tmp_path / "o").exists()


def test_eval_set_takes_only_client_settings(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["eval", str(tmp_path), "--set", "field.hidden=8"])
    assert result.exit_code == 2
    assert "--set field.hidden: not a setting you may change" in result.output
