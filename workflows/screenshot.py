"""Screenshots of the web studio in headless Chromium (Debian's ``chromium``, driven by Playwright;
no browser download). ``proctex screenshot URL --out studio.png``.

WebGL runs on SwiftShader (no GPU needed); the page is shot once the studio reports a finished
transfer (``document.body.dataset.state == "idle"`` with at least one completed request).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

#: Chromium flags for a headless, GPU-less, offline machine: SwiftShader WebGL, and none of
#: Chromium's background network traffic (refused here, and slow to fail).
CHROMIUM_ARGS = [
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--ignore-gpu-blocklist",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]


def chromium_path() -> str | None:
    """Debian's Chromium, if installed (``make test`` installs it)."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    return found or ("/usr/bin/chromium" if os.path.isfile("/usr/bin/chromium") else None)


def studio_screenshot(url: str, out: str | os.PathLike, params: dict[str, Any] | None = None, width: int = 1280, height: int = 800, timeout: float = 60.0) -> dict[str, Any]:
    """Open the studio at ``url`` (e.g. ``http://127.0.0.1:8000/?family=sofa``), optionally set
    parameter sliders/selects (``params``), wait for the textured shape and save a PNG at ``out``.

    Returns what the page reported: family, parameter values, requests, client and server latency.
    Raises ``ValueError`` for a missing browser or Playwright, a bad URL or size, unknown
    parameters, or a page that ends in its error state.
    """
    if not url.startswith(("http://", "https://")):
        raise ValueError(f"url must start with http:// or https://, got {url!r}")
    if not (200 <= width <= 4096 and 200 <= height <= 4096):
        raise ValueError(f"the window must be 200..4096 pixels a side, got {width}x{height}")
    if Path(out).suffix.lower() != ".png":
        raise ValueError(f"--out must name a .png file, got {str(out)!r}")
    exe = chromium_path()
    if exe is None:
        raise ValueError("Chromium is not installed (Debian: apt-get install chromium; `make test` installs it)")
    try:
        from playwright.sync_api import Error as PlaywrightError
        from playwright.sync_api import sync_playwright
    except ImportError as exc:
        raise ValueError("playwright (Python) is not installed; it is in the dev extras (`make setup`)") from exc

    wait = "n => document.body.dataset.state === 'idle' && document.body.dataset.busy === '0' && +document.body.dataset.requests >= n"
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": width, "height": height})
            try:
                page.goto(url, timeout=timeout * 1000)
                page.wait_for_function("() => (document.body.dataset.state === 'idle' && +document.body.dataset.requests >= 1) || document.body.dataset.state === 'error'", timeout=timeout * 1000)
            except PlaywrightError as exc:
                raise ValueError(f"the studio at {url} did not show a shape within {timeout:g}s: {str(exc).splitlines()[0]}") from exc
            for name, value in (params or {}).items():
                n = int(page.evaluate("document.body.dataset.requests"))
                found = page.evaluate(
                    """([name, value]) => {
                        const el = document.querySelector(`[name="${CSS.escape(name)}"]`);
                        if (!el) return false;
                        el.value = String(value);
                        el.dispatchEvent(new Event('input', {bubbles: true}));
                        el.dispatchEvent(new Event('change', {bubbles: true}));
                        return true;
                    }""",
                    [name, value],
                )
                if not found:
                    raise ValueError(f"the studio has no control for parameter {name!r}")
                page.wait_for_function(wait, arg=n + 1, timeout=timeout * 1000)
            if page.evaluate("document.body.dataset.state") == "error":
                text = page.evaluate("(document.getElementById('error') || {}).textContent || ''")
                raise ValueError(f"the studio shows an error: {text.strip() or 'unknown'}")
            Path(out).parent.mkdir(parents=True, exist_ok=True)
            tmp = f"{out}.tmp{os.getpid()}.png"
            page.screenshot(path=tmp)
            os.replace(tmp, out)
            info = page.evaluate("""() => ({family: document.getElementById('family').value, params: window.studio.lastParams,
                                             requests: +document.body.dataset.requests, client_ms: window.studio.lastLatencyMs,
                                             server_seconds: window.studio.lastServerSeconds})""")
        finally:
            browser.close()
    return dict(info)
