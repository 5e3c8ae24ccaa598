"""Driving the explorer in a real headless Chromium (Debian's `chromium` + `chromium-driver`, via Selenium):
what the tests and the latency benchmark do, as a person would (keys on a slider, typing into a box).

Panel draws every widget inside shadow DOMs, so elements are found by a search through the shadow roots.
Latencies are measured in the browser's own clock: from the key event on the slider to the DOM change of
the numbers table, and to Plotly's `plotly_afterplot` of the particle view showing the new point.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from neuraldem.errors import ConfigError

# installed once per page load: a search through the shadow roots, and the latency probe. Before a timed key
# the probe is told the point the key leads to; it takes the time of the key event, of the DOM mutation that
# puts that point into the numbers table (a MutationObserver), of Plotly's `plotly_afterplot` on the particle
# view titled with it (the figure redrawn), and of the second animation frame after that (painted)
PAGE_JS = """
if (window.ndDeep) return true;
function deepAll(root, s, out) {
  for (const h of root.querySelectorAll(s)) out.push(h);
  for (const el of root.querySelectorAll('*')) if (el.shadowRoot) deepAll(el.shadowRoot, s, out);
  return out;
}
window.ndAll = (s) => deepAll(document, s, []);
window.ndDeep = (s) => window.ndAll(s)[0] || null;
// an element inside a widget: Panel puts the widget's CSS class on the host of the shadow root holding it
window.ndWithin = (host, inner) => {
  for (const h of window.ndAll(host)) {
    const hit = deepAll(h.shadowRoot || h, inner, []);
    if (hit.length) return hit[0];
  }
  return null;
};
const titled = (gd, prefix) => gd.layout && gd.layout.title && String(gd.layout.title.text).startsWith(prefix);
window.ndShows = (point) => {
  const status = window.ndDeep('#hopper-status');
  return !!status && status.dataset.point === point &&
    window.ndAll('.js-plotly-plot').some(g => titled(g, point + ','));
};
const probe = window.ndProbe = {key: null, point: null, prefix: null, numbers: null, fields: null, painted: null};
document.addEventListener('keydown', () => { probe.key = performance.now(); }, true);
// point: the numbers to wait for (null: they do not change); prefix: the particle view's title to wait for
window.ndExpect = (point, prefix) => {
  Object.assign(probe, {point: point, prefix: prefix, key: null, numbers: null, fields: null, painted: null});
  const table = window.ndDeep('#hopper-numbers');
  const root = table.getRootNode();
  if (!root.ndObserved) {
    root.ndObserved = true;
    new MutationObserver(() => {
      const t = root.querySelector('#hopper-numbers');
      if (probe.key !== null && probe.numbers === null && t && t.dataset.point === probe.point)
        probe.numbers = performance.now();
    }).observe(root, {childList: true, subtree: true, attributes: true});
  }
  for (const gd of window.ndAll('.js-plotly-plot')) {
    if (gd.ndObserved || !gd.on) continue;
    gd.ndObserved = true;
    gd.on('plotly_afterplot', () => {
      if (probe.key === null || probe.fields !== null || !titled(gd, probe.prefix)) return;
      probe.fields = performance.now();
      requestAnimationFrame(() => requestAnimationFrame(() => { probe.painted = performance.now(); }));
    });
  }
};
return true;
"""

def chromium_paths() -> tuple[str, str] | None:
    """(browser, driver) when Debian's chromium and chromium-driver are installed, else None."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    return (browser, driver) if browser and driver else None


def start_chromium(width: int = 1200, height: int = 1000) -> Any:
    """A headless Chromium under Selenium (WebGL through SwiftShader, for Plotly's 3D view)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    paths = chromium_paths()
    if paths is None:
        raise ConfigError("chromium and chromedriver are not installed",
                          "apt-get install chromium chromium-driver (scripts/setup.sh does)")
    options = webdriver.ChromeOptions()
    options.binary_location = paths[0]
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", f"--window-size={width},{height}",
                "--enable-unsafe-swiftshader", "--use-angle=swiftshader", "--disable-gpu-sandbox",
                "--disable-extensions", "--mute-audio"):
        options.add_argument(arg)
    return webdriver.Chrome(service=Service(paths[1]), options=options)


def wait_for(check: Callable[[], Any], timeout: float, what: str, poll: float = 0.05) -> Any:
    """The first truthy value of `check()`, or TimeoutError naming `what`."""
    end = time.monotonic() + timeout
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > end:
            raise TimeoutError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(poll)


def find(driver: Any, selector: str) -> Any:
    """The first element matching `selector`, through the shadow roots (after PAGE_JS ran)."""
    return driver.execute_script("return window.ndDeep(arguments[0]);", selector)


class PageBrowser:
    """What every explorer page offers a browser test: its notes and status line (ids `<prefix>-notes`,
    `<prefix>-status`), keyboard arrows on a slider or the time player, typing into a value box, screenshots."""

    prefix = ""

    def __init__(self, driver: Any, timeout: float):
        self.driver, self.timeout = driver, timeout

    def notes(self) -> list[str]:
        """The lines under the sliders (read in one script: Panel replaces the element on every update)."""
        return self.driver.execute_script(f"const n = window.ndDeep('#{self.prefix}-notes'); "
                                          "return n ? [...n.querySelectorAll('li')].map(li => li.textContent) : [];")

    def status(self, name: str) -> str | None:
        """An attribute (`data-<name>`) of the page's status line."""
        return self.driver.execute_script(f"const s = window.ndDeep('#{self.prefix}-status'); "
                                          "return s ? s.getAttribute(arguments[0]) : null;", f"data-{name}")

    def within(self, host: str, inner: str) -> Any:
        return self.driver.execute_script("return window.ndWithin(arguments[0], arguments[1]);", host, inner)

    def press_slider(self, key: str, arrow: str = "right", times: int = 1) -> None:
        """Keyboard arrows on slider `key`'s handle: each press moves it one step (as a person would)."""
        from selenium.webdriver.common.keys import Keys

        handle = self.within(f".nd-slider-{key}", ".noUi-handle")
        if handle is None:
            raise LookupError(f"no slider for {key} on the page")
        handle.send_keys(*([Keys.ARROW_RIGHT if arrow == "right" else Keys.ARROW_LEFT] * times))

    def press_time(self, arrow: str = "right") -> None:
        """Keyboard arrows on the time slider (the player's range input)."""
        from selenium.webdriver.common.keys import Keys

        slider = self.within(".nd-time", "input[type=range]")
        if slider is None:
            raise LookupError("no time slider on the page")
        slider.send_keys(Keys.ARROW_RIGHT if arrow == "right" else Keys.ARROW_LEFT)

    def type_into(self, key: str, text: str) -> None:
        """Type `text` into the value box of `key` and press Enter (typing replaces the old value)."""
        from selenium.webdriver.common.keys import Keys

        box = self.within(f".nd-typed-{key}", "input")
        if box is None:
            raise LookupError(f"no text box for {key} on the page")
        self.driver.execute_script("arguments[0].value = '';", box)
        box.send_keys(text, Keys.ENTER)

    def screenshot(self, path: Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        self.driver.save_screenshot(str(path))
        return path


class ServerProcess:
    """`neuraldem serve` in a child process on a free port of this machine, stopped on exit (a context
    manager): what the tests and the benchmark drive."""

    def __init__(self, args: list[str], env: dict[str, str] | None = None, timeout: float = 120.0,
                 host: str = "127.0.0.1"):
        import os
        import subprocess
        import sys
        import tempfile

        from neuraldem.serve.ports import free_port

        self.port = free_port(host)
        self.url = f"http://{host}:{self.port}/hopper"
        self.log = tempfile.TemporaryFile(mode="w+")  # noqa: SIM115 (kept open while the server runs)
        child_env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1"),
                     "OMP_WAIT_POLICY": "PASSIVE", **(env or {})}
        self.proc = subprocess.Popen([sys.executable, "-m", "neuraldem", "serve", f"host={host}",
                                      f"port={self.port}", *args], env=child_env, stdout=self.log,
                                     stderr=subprocess.STDOUT, text=True)
        self.timeout = timeout

    def __enter__(self) -> ServerProcess:
        try:
            wait_for(lambda: self.proc.poll() is not None or self._up(), self.timeout, f"the server at {self.url}",
                     poll=0.25)
            if self.proc.poll() is not None:
                raise RuntimeError(f"neuraldem serve exited with {self.proc.returncode}:\n{self.output()}")
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _up(self) -> bool:
        import urllib.request

        try:
            with urllib.request.urlopen(self.url.rsplit("/", 1)[0] + "/", timeout=2) as r:
                return r.status == 200
        except OSError:
            return False

    def output(self) -> str:
        self.log.seek(0)
        return self.log.read()

    def stop(self) -> None:
        import subprocess

        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
