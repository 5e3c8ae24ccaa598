"""The explorer latency benchmark's arithmetic and table (the browser part runs in tests/serve)."""

from __future__ import annotations

from neuraldem.bench.serve_latency import TARGETS_MS, markdown, parse_point, point_text, summary


def rows(numbers: list[float], fields: list[float]) -> list[dict]:
    return [{"numbers_ms": n, "fields_ms": f, "painted_ms": f + 100, "server_frame_ms": 20.0}
            for n, f in zip(numbers, fields, strict=True)]


def test_median_p90_and_max_per_latency():
    s = summary(rows([50, 70, 60, 500], [200, 250, 220, 900]))
    assert s["numbers_ms"] == {"median": 65.0, "p90": 500, "max": 500, "n": 4}
    assert s["fields_ms"]["median"] == 235.0 and s["painted_ms"]["max"] == 1000
    assert "numbers_ms" not in summary([{"numbers_ms": None, "fields_ms": 100, "painted_ms": 150}])


def test_the_table_says_which_target_is_met():
    result = {"model": "m", "command": "neuraldem bench serve_latency", "browser": "chrome 1",
              "pause_s": 1.0, "warmup": 3, "machine": {"load_average_1_5_15min": [0.2], "cpu_count": 2},
              "summary": {"parameter_moves": summary(rows([80, 90], [350, 400])),
                          "time_moves": summary(rows([0, 0], [100, 120]))}}
    md = markdown(result)
    assert "| parameter slider -> numbers (DOM) | 2 | 85 (met) |" in md
    assert f"(over {TARGETS_MS['fields_ms']:.0f})" in md and "| time slider -> particles redrawn | 2 | 110 (met)" in md


def test_points_read_back_as_the_page_writes_them():
    values = {"alpha": 40.5, "mu_s": 0.31, "mu_r": 0.105}
    assert parse_point(point_text(values)) == values
