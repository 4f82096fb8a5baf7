"""The report page opens in headless Chromium with every image loaded and no console
message, and is written by harmap.run beside the atlas."""

import re
import subprocess
from pathlib import Path

import pytest

import harmap

FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
    "--disable-crash-reporter",
    "--disable-breakpad",
]

# Appended to a copy of the page: after load, count the images that did not decode and
# write the counts into the document, which --dump-dom then prints.
CHECK = """<script>
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var broken = imgs.filter(function (i) { return !i.complete || i.naturalWidth === 0; });
  var p = document.createElement('p');
  p.id = 'harmap-check';
  p.textContent = 'images=' + imgs.length + ' broken=' + broken.length;
  document.body.appendChild(p);
});
</script>"""


class Output:
    def __init__(self, stdout, stderr):
        self.stdout, self.stderr = stdout, stderr


def chrome(chromium, profile, *args, timeout=300):
    # Output to files, not pipes: helper processes of Chromium may keep a pipe open
    # after the browser has exited, and reading it to its end would then hang.
    out, err = Path(f"{profile}.out"), Path(f"{profile}.err")
    with out.open("w") as o, err.open("w") as e:
        subprocess.run(
            [chromium, *FLAGS, f"--user-data-dir={profile}", *args],
            stdin=subprocess.DEVNULL,
            stdout=o,
            stderr=e,
            timeout=timeout,
        )
    return Output(out.read_text(), err.read_text())


def check_page(chromium, page, tmp_path, screenshot):
    """Screenshot `page`, then check its images and the console; returns the count of
    images."""
    url = page.resolve().as_uri()
    r = chrome(
        chromium,
        tmp_path / "profile1",
        "--enable-logging=stderr",
        "--v=0",
        "--window-size=1280,3600",
        f"--screenshot={screenshot}",
        url,
    )
    assert screenshot.exists() and screenshot.stat().st_size > 10_000, r.stderr
    console = [l for l in r.stderr.splitlines() if "CONSOLE" in l or "Failed to load resource" in l]
    assert not console, "console messages:\n" + "\n".join(console)
    checked = tmp_path / "checked.html"
    checked.write_text(page.read_text().replace("</body>", CHECK + "</body>"))
    r = chrome(
        chromium,
        tmp_path / "profile2",
        "--enable-logging=stderr",
        "--v=0",
        "--virtual-time-budget=5000",
        "--dump-dom",
        checked.resolve().as_uri(),
    )
    m = re.search(r"images=(\d+) broken=(\d+)", r.stdout)
    assert m, f"the check did not run:\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}"
    assert int(m.group(2)) == 0, f"{m.group(2)} of {m.group(1)} images broken"
    console = [l for l in r.stderr.splitlines() if "CONSOLE" in l]
    assert not console, "console messages:\n" + "\n".join(console)
    return int(m.group(1))


def test_the_starfish_report_opens_in_chromium_without_broken_images(chromium, tmp_path):
    r = harmap.run(None, out=tmp_path / "starfish.harmap", progress=False)
    page = tmp_path / "starfish.report.html"
    assert page.exists(), "harmap.run writes the report beside the run"
    text = page.read_text()
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//)""", text), "an external URL"
    shot = tmp_path / "report-starfish.png"
    n = check_page(chromium, page, tmp_path, shot)
    # The atlas, the sphere and three slices each of phi, theta and psi.
    assert n == 11
    assert r.done("map")
