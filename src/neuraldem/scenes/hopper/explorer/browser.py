"""The hopper page in headless Chromium: its browser tests and latency benchmark drive it with the keyboard."""

from __future__ import annotations

from typing import Any

from neuraldem.serve.browser import PAGE_JS, PageBrowser, wait_for


class HopperBrowser(PageBrowser):
    """The hopper page in a browser: read its numbers, move its sliders, type values, time the updates."""

    prefix = "hopper"

    def __init__(self, driver: Any, url: str, timeout: float = 60.0):
        super().__init__(driver, timeout)
        driver.get(url)
        wait_for(lambda: driver.execute_script(PAGE_JS) and self.status_point() is not None, timeout,
                 "the hopper page's first frame")

    # ---- reading
    def numbers(self) -> dict[str, Any] | None:
        """{"point": "alpha=.. ..", "gp": {key: (mean, low, high)}, "field": {key: value} (empty while it
        computes), "stored": {key: value}, "regime": [...], "text": {key: [cell texts]}} (None before the
        page shows them). Values are read from the cells' exact decimals (nan included)."""
        raw = self.driver.execute_script(READ_NUMBERS)
        if raw is None:
            return None
        raw["gp"] = {k: tuple(float(x) for x in v) for k, v in raw["gp"].items()}
        for part in ("field", "stored"):
            raw[part] = {k: float(v) for k, v in raw[part].items()}
        return raw

    def status_point(self) -> str | None:
        return self.status("point")

    def shows(self, point: str) -> bool:
        """Whether the particle view and the status line show `point`."""
        return bool(self.driver.execute_script("return window.ndShows(arguments[0]);", point))

    # ---- acting
    def press(self, key: str, arrow: str = "right", times: int = 1) -> None:
        self.press_slider(key, arrow, times)

    def type_value(self, key: str, text: str) -> None:
        self.type_into(key, text)

    def wait_numbers_for(self, point: str, timeout: float | None = None) -> dict[str, Any]:
        return wait_for(lambda: (n := self.numbers()) and n["point"] == point and n, timeout or self.timeout,
                        f"the numbers of {point}")

    def wait_numbers_change(self, old_point: str, timeout: float | None = None) -> dict[str, Any]:
        return wait_for(lambda: (n := self.numbers()) and n["point"] != old_point and n, timeout or self.timeout,
                        f"the numbers to leave {old_point}")

    def wait_for_note(self, note: str, timeout: float | None = None) -> list[str]:
        return wait_for(lambda: note in (notes := self.notes()) and notes, timeout or self.timeout, f"note {note!r}")

    def wait_field_numbers(self, timeout: float | None = None) -> dict[str, Any]:
        return wait_for(lambda: (n := self.numbers()) and n["field"] and n, timeout or self.timeout,
                        "the field model's numbers")

    def wait_frame_for(self, point: str, timeout: float | None = None) -> str:
        return wait_for(lambda: self.shows(point) and point, timeout or self.timeout, f"the particles of {point}")

    def timed_press(self, key: str, point: str, arrow: str = "right", timeout: float | None = None) -> dict[str, float]:
        """One key on slider `key`, which must lead to `point`: milliseconds from the key event to the numbers
        of `point` in the page's DOM, to its particle view redrawn by Plotly, and to that view painted."""
        self.driver.execute_script(EXPECT_JS, point, point + ",")
        self.press(key, arrow)
        return self._latency(point, timeout)

    def timed_time_step(self, point: str, t: float, arrow: str = "right",
                        timeout: float | None = None) -> dict[str, float]:
        """One key on the time slider, which must lead to time `t` at `point`: as `timed_press` (the numbers
        do not change, so only the particle view is timed)."""
        self.driver.execute_script(EXPECT_JS, None, f"{point}, t = {t:.2f} s")
        self.press_time(arrow)
        return self._latency(f"{point} at t = {t:.2f} s", timeout)

    def _latency(self, what: str, timeout: float | None) -> dict[str, float]:
        result = wait_for(lambda: self.driver.execute_script(LATENCY_JS), timeout or self.timeout,
                          f"the updates of {what}")
        return {"numbers_ms": result[0], "fields_ms": result[1], "painted_ms": result[2]}


READ_NUMBERS = """
const table = window.ndDeep('#hopper-numbers');
if (!table) return null;
const out = {point: table.dataset.point, gp: {}, field: {}, stored: {}, regime: [], text: {}};
for (const row of table.querySelectorAll('tr[data-key]')) {
  const key = row.dataset.key;
  out.text[key] = [...row.querySelectorAll('td')].slice(1).map(c => c.textContent);
  if (key === 'regime') { out.regime = out.text[key]; continue; }
  const gp = row.querySelector('td.gp'), field = row.querySelector('td.field'), st = row.querySelector('td.stored');
  out.gp[key] = [gp.dataset.mean, gp.dataset.low, gp.dataset.high];
  if (field && field.dataset.value !== undefined) out.field[key] = field.dataset.value;
  if (st) out.stored[key] = st.dataset.value;
}
return out;
"""
EXPECT_JS = "window.ndExpect(arguments[0], arguments[1]);"
LATENCY_JS = """
const p = window.ndProbe;
if ((p.point !== null && p.numbers === null) || p.painted === null) return null;
return [p.point === null ? null : p.numbers - p.key, p.fields - p.key, p.painted - p.key];
"""
