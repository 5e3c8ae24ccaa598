"""The bed page in a real headless Chromium (through `serve/browser.py`: its driver, shadow-DOM search and
server process): read the numbers, move the velocity slider, type a value, time the updates.

Latencies are taken in the browser's own clock, from the key event on the slider to the DOM change that puts
the new velocity into the numbers table, and to Plotly's `plotly_afterplot` of the fields figure titled with
the new velocity (what that figure shows then is the nearest ready rollout: its velocity is read back too).
"""

from __future__ import annotations

from typing import Any

from neuraldem.serve.browser import PAGE_JS, PageBrowser, wait_for

# the bed's latency probe, installed after browser.PAGE_JS (which gives ndDeep / ndAll / ndWithin)
BED_JS = """
if (window.ndBed) return true;
const bed = window.ndBed = {key: null, velocity: null, prefix: null, numbers: null, fields: null, painted: null};
document.addEventListener('keydown', () => { bed.key = performance.now(); }, true);
const titled = (gd, prefix) => gd.layout && gd.layout.title && String(gd.layout.title.text).startsWith(prefix);
window.ndBedExpect = (velocity, prefix) => {
  Object.assign(bed, {velocity: velocity, prefix: prefix, key: null, numbers: null, fields: null, painted: null});
  const table = window.ndDeep('#bed-numbers');
  const root = table.getRootNode();
  if (!root.ndBedObserved) {
    root.ndBedObserved = true;
    new MutationObserver(() => {
      const t = root.querySelector('#bed-numbers');
      if (bed.key !== null && bed.numbers === null && t && Number(t.dataset.velocity) === bed.velocity)
        bed.numbers = performance.now();
    }).observe(root, {childList: true, subtree: true, attributes: true});
  }
  for (const gd of window.ndAll('.js-plotly-plot')) {
    if (gd.ndBedObserved || !gd.on) continue;
    gd.ndBedObserved = true;
    gd.on('plotly_afterplot', () => {
      if (bed.key === null || bed.fields !== null || !titled(gd, bed.prefix)) return;
      bed.fields = performance.now();
      bed.title = gd.layout.title.text;
      requestAnimationFrame(() => requestAnimationFrame(() => { bed.painted = performance.now(); }));
    });
  }
};
window.ndBedFields = () => window.ndAll('.js-plotly-plot').find(g => titled(g, 'inlet velocity')) || null;
return true;
"""
READ_NUMBERS = """
const table = window.ndDeep('#bed-numbers');
if (!table) return null;
const out = {velocity: Number(table.dataset.velocity), gp: {}, field: {}, text: {}};
for (const row of table.querySelectorAll('tr[data-key]')) {
  const key = row.dataset.key;
  out.text[key] = [...row.querySelectorAll('td')].slice(1).map(c => c.textContent);
  const gp = row.querySelector('td.gp'), field = row.querySelector('td.field');
  out.gp[key] = [gp.dataset.mean, gp.dataset.low, gp.dataset.high];
  if (field && field.dataset.value !== undefined) out.field[key] = field.dataset.value;
}
return out;
"""
LATENCY_JS = """
const p = window.ndBed;
if (p.numbers === null || p.painted === null) return null;
return [p.numbers - p.key, p.fields - p.key, p.painted - p.key, p.title];
"""


def page_url(server_url: str, route: str = "bed") -> str:
    """The bed page of a `browser.ServerProcess` (whose url is its hopper page's)."""
    return server_url.rsplit("/", 1)[0] + "/" + route


class BedBrowser(PageBrowser):
    """The bed page in a browser (status attributes: model, velocity, shown (the rollout's velocity), time,
    frames, lattice, ready)."""

    prefix = "bed"

    def __init__(self, driver: Any, url: str, timeout: float = 60.0):
        super().__init__(driver, timeout)
        driver.get(url)
        wait_for(lambda: driver.execute_script(PAGE_JS) and driver.execute_script(BED_JS)
                 and self.status("velocity") is not None and self.numbers() is not None, timeout, "the bed page")

    # ---- reading
    def numbers(self) -> dict[str, Any] | None:
        """{"velocity": v, "gp": {key: (mean, low, high)}, "field": {key: value} (empty while the exact rollout
        computes), "text": {key: [cell texts]}}, values from the cells' exact decimals."""
        raw = self.driver.execute_script(READ_NUMBERS)
        if raw is None:
            return None
        raw["gp"] = {k: tuple(float(x) for x in v) for k, v in raw["gp"].items()}
        raw["field"] = {k: float(v) for k, v in raw["field"].items()}
        return raw

    def fields_title(self) -> str | None:
        return self.driver.execute_script("const g = window.ndBedFields(); "
                                          "return g ? String(g.layout.title.text) : null;")

    # ---- acting
    def press(self, arrow: str = "right", times: int = 1) -> None:
        self.press_slider("inlet_velocity", arrow, times)

    def type_value(self, text: str) -> None:
        self.type_into("inlet_velocity", text)

    # ---- waiting
    def wait_numbers_for(self, velocity: float, timeout: float | None = None) -> dict[str, Any]:
        return wait_for(lambda: (n := self.numbers()) and n["velocity"] == velocity and n, timeout or self.timeout,
                        f"the numbers of {velocity:g} m/s")

    def wait_field_numbers(self, velocity: float, timeout: float | None = None) -> dict[str, Any]:
        return wait_for(lambda: (n := self.numbers()) and n["velocity"] == velocity and n["field"] and n,
                        timeout or self.timeout, f"the field model's numbers at {velocity:g} m/s")

    def wait_shown(self, velocity: float, timeout: float | None = None) -> str:
        """Until the fields show the exact rollout at `velocity`; its title."""
        prefix = f"inlet velocity {velocity:g} m/s: rollout at {velocity:g} m/s (exact)"
        return wait_for(lambda: (t := self.fields_title()) and t.startswith(prefix) and t, timeout or self.timeout,
                        f"the exact rollout at {velocity:g} m/s drawn")

    def timed_press(self, velocity: float, arrow: str = "right", timeout: float | None = None) -> dict[str, Any]:
        """One key on the velocity slider, which must lead to `velocity`: milliseconds from the key event to its
        numbers in the DOM, to the fields figure redrawn for it (plotly_afterplot) and painted, and the title
        then drawn (which names the rollout shown)."""
        self.driver.execute_script("window.ndBedExpect(arguments[0], arguments[1]);", velocity,
                                   f"inlet velocity {velocity:g} m/s:")
        self.press(arrow)
        r = wait_for(lambda: self.driver.execute_script(LATENCY_JS), timeout or self.timeout,
                     f"the updates of {velocity:g} m/s")
        return {"numbers_ms": r[0], "fields_ms": r[1], "painted_ms": r[2], "fields_title": r[3]}
