"""What the browser tests share: where Chromium is, how it starts (with WebGL or without), the
script that makes the page send the suite's tiny config, the progress bar's samples, and the
axe-core scan."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tests.configs import tiny_request

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists()
                                         else None)
LAUNCH_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
               "--disable-component-update", "--disable-sync"]
# WebGL without a GPU (the 3D viewer): Chromium's software rasteriser, allowed explicitly.
WEBGL_LAUNCH_ARGS = ["--headless", "--no-sandbox", "--use-angle=swiftshader",
                     "--enable-unsafe-swiftshader", "--disable-background-networking",
                     "--disable-component-update", "--disable-sync"]
AXE = ROOT / "node_modules" / "axe-core" / "axe.min.js"
# The suite's tiny config is no public preset: the page sends the preset it offers, and this
# script swaps in the tiny preset (which the test process registered) and merges the given
# settings into the config field it posts, as an API client could.
_CONFIG_SCRIPT = """
(() => {
  const tiny = TINY_JSON;
  const append = FormData.prototype.append;
  FormData.prototype.append = function (name, value, ...rest) {
    if (name === "config") {
      const config = JSON.parse(value);
      config.preset = TINY_NAME;
      const overrides = config.overrides || {};
      for (const [key, val] of Object.entries(tiny)) {
        overrides[key] = (val && typeof val === "object" && overrides[key])
          ? { ...val, ...overrides[key] } : val;
      }
      config.overrides = overrides;
      value = JSON.stringify(config);
    }
    return append.call(this, name, value, ...rest);
  };
})();
"""


def tiny_config_script(**overrides: Any) -> str:
    """The init script that makes the page send the tiny config, with ``overrides`` merged on
    top as ``tests.configs.tiny_request`` merges them."""
    request = tiny_request(**overrides)
    return (_CONFIG_SCRIPT.replace("TINY_JSON", json.dumps(request["overrides"]))
            .replace("TINY_NAME", json.dumps(request["preset"])))


TINY_CONFIG_SCRIPT = tiny_config_script()


def axe_missing_reason() -> str | None:
    """Why the axe-core scan cannot run here, or None when it can."""
    if AXE.is_file():
        return None
    if shutil.which("npm") is None:
        return "node/npm is absent, so axe-core (npm) is not installed for the accessibility scan"
    return "axe-core is not installed: run `make test`, or `npm ci` in the repository root"


def axe_violations(page: Any) -> list[dict[str, Any]]:
    """Run axe-core on the page as it is; its violations (id, impact, nodes' targets)."""
    if not page.evaluate("() => typeof window.axe === 'object'"):
        page.add_script_tag(path=str(AXE))
    found = page.evaluate(
        "async () => (await axe.run(document, { resultTypes: ['violations'] })).violations"
        ".map((v) => ({ id: v.id, impact: v.impact, help: v.help,"
        " targets: v.nodes.map((n) => n.target.join(' ')) }))")
    return list(found)


def progress_samples(page: Any, check: Callable[[], None] | None = None) -> list[float]:
    """Widths (percent) of the progress bar, sampled until the job ends; ``check`` (if any) runs
    on every sample taken before the result appears, so it sees the page while the job runs."""
    widths: list[float] = []
    for _ in range(1500):
        width = page.evaluate("() => parseFloat(document.getElementById('bar-fill').style.width)"
                              " || 0")
        widths.append(float(width))
        if not page.locator("#result").is_hidden() or page.locator("#job-error").is_visible():
            break
        if check is not None:
            check()
        page.wait_for_timeout(200)
    assert not page.locator("#job-error").is_visible(), page.inner_text("#job-error")
    return widths


def drag_across(page: Any, selector: str, start: float, end: float) -> None:
    """Drag the mouse across the middle of an element, from ``start`` to ``end`` of its width
    (fractions), in eight moves, as a user turning a 3D view does."""
    box = page.locator(selector).bounding_box()
    assert box is not None, f"{selector} is not on the page"
    y = box["y"] + box["height"] / 2
    page.mouse.move(box["x"] + box["width"] * start, y)
    page.mouse.down()
    page.mouse.move(box["x"] + box["width"] * end, y, steps=8)
    page.mouse.up()
