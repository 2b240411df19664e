"""Open a report.html in headless Chromium and read back what a reader's browser sees.

A copy of the page gets a tiny script that records script errors, console errors, images
that failed to decode (naturalWidth 0) and the page's scroll width against the window's;
Chromium renders it with --dump-dom and the script's findings are parsed from the DOM.
The page itself is never modified. Used by tests/test_report_browser.py and by hand:

    python tests/browser.py fits/reference/report.html --width 800 --shot /tmp/r800.png
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile

PROBE = """<script>
window.__fl = {errors: [], console: []};
window.addEventListener('error', function (e) {
  window.__fl.errors.push(String(e.message || (e.target && e.target.src && 'load failed')));
}, true);
(function () {
  var ce = console.error;
  console.error = function () {
    window.__fl.console.push(Array.prototype.join.call(arguments, ' '));
    return ce.apply(console, arguments);
  };
})();
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var broken = imgs.filter(function (i) { return !i.complete || i.naturalWidth === 0; })
                   .map(function (i) { return i.alt; });
  var noalt = imgs.filter(function (i) { return !i.alt; }).length;
  var out = {errors: window.__fl.errors, console: window.__fl.console, images: imgs.length,
             broken: broken, noalt: noalt, inner: window.innerWidth,
             scroll: document.documentElement.scrollWidth, height:
             document.documentElement.scrollHeight};
  var pre = document.createElement('pre');
  pre.id = '__fitlug_probe';
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script>"""


def chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def _run(args, timeout):
    return subprocess.run(args, capture_output=True, text=True, timeout=timeout)


def _flags(width, height):
    return ["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
            "--disable-dev-shm-usage", "--no-first-run", "--allow-file-access-from-files",
            f"--window-size={width},{height}", "--virtual-time-budget=10000"]


def probe(page: str, width: int = 1200, height: int = 900, timeout: float = 120) -> dict:
    """What the browser saw: {"errors", "console", "images", "broken", "noalt", "inner",
    "scroll", "height"}. Raises RuntimeError when Chromium cannot run or report."""
    exe = chromium()
    if exe is None:
        raise RuntimeError("chromium not found")
    text = open(page, encoding="utf-8").read()
    probed = re.sub(r"(<head[^>]*>)", lambda m: m.group(1) + PROBE, text, count=1)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "report.html")
        with open(path, "w", encoding="utf-8") as f:
            f.write(probed)
        r = _run([exe, *_flags(width, height), "--dump-dom", "file://" + path], timeout)
    m = re.search(r'<pre id="__fitlug_probe">(.*?)</pre>', r.stdout, re.S)
    if not m:
        raise RuntimeError(f"chromium gave no probe (rc {r.returncode}): {r.stderr[-800:]}")
    import html

    return json.loads(html.unescape(m.group(1)))


def screenshot(page: str, png: str, width: int = 1200, height: int = 2000,
               timeout: float = 120) -> str:
    """A PNG of the page's first `height` pixels at `width` (for looking at it)."""
    exe = chromium()
    if exe is None:
        raise RuntimeError("chromium not found")
    png = os.path.abspath(png)
    _run([exe, *_flags(width, height), f"--screenshot={png}",
          "file://" + os.path.abspath(page)], timeout)
    if not os.path.isfile(png):
        raise RuntimeError("chromium wrote no screenshot")
    return png


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("page")
    ap.add_argument("--width", type=int, default=1200)
    ap.add_argument("--height", type=int, default=2000)
    ap.add_argument("--shot")
    a = ap.parse_args()
    print(json.dumps(probe(a.page, a.width), indent=1))
    if a.shot:
        print(screenshot(a.page, a.shot, a.width, a.height))
    sys.exit(0)
