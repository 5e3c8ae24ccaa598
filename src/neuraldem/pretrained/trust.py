"""Which answer to trust: per quantity, the source (GP or field model) with the lower validated error at that point.

A released model records its sources' errors on held-out solver runs inside its trained ranges (`test_errors` in
meta.json), optionally their errors outside them (`test_errors_outside`, from runs beyond the ranges) and the
regions where it is known to be weak (`weak_regions`: `{"parameters": {name: [lo, hi]}, "note": ...}`). The rule:
- inside the trained ranges: the source with the lower recorded error on that quantity;
- outside them: the lower error recorded outside when there is one, else no recommendation (neither answer was
  validated there), and the reason says so;
- inside a known weak region: the same choice, with a warning naming the region.
Each choice comes with a one-line reason that quotes the errors it compared.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

SOURCES = ("gp", "field model")
LABELS = {"gp": "GP", "field model": "field model"}


@dataclass(frozen=True)
class ErrorKey:
    """How a quantity's validated error is recorded: its key in `test_errors[source]`, its unit, and whether a
    larger value is better (an accuracy) or worse (an error)."""

    key: str
    unit: str = ""
    higher_is_better: bool = False


@dataclass(frozen=True)
class Recommendation:
    source: str | None  # "gp", "field model", or None (neither validated here)
    reason: str
    warning: str | None = None


def _value(errors: Mapping[str, Any], source: str, key: str) -> float | None:
    v = (errors.get(source) or {}).get(key)
    return None if v is None or v != v else float(v)


def _choose(errors: Mapping[str, Any], err: ErrorKey, where: str) -> Recommendation:
    values = {s: _value(errors, s, err.key) for s in SOURCES}
    known = {s: v for s, v in values.items() if v is not None}
    if not known:
        return Recommendation(None, f"no validated error {where}")
    best = max(known, key=known.get) if err.higher_is_better else min(known, key=known.get)  # type: ignore[arg-type]
    quoted = ", ".join(f"{LABELS[s]} {v:.3g}{err.unit}" for s, v in known.items())
    return Recommendation(best, f"lower validated error {where} ({quoted})" if not err.higher_is_better
                          else f"higher validated accuracy {where} ({quoted})")


def in_region(point: Mapping[str, float], region: Mapping[str, Any]) -> bool:
    bounds = region.get("parameters", {})
    return bool(bounds) and all(k in point and lo <= point[k] <= hi for k, (lo, hi) in bounds.items())


def recommend(meta: Mapping[str, Any], point: Mapping[str, float], extrapolating: bool,
              error_keys: Mapping[str, ErrorKey]) -> dict[str, Recommendation]:
    """The recommended source per quantity of `error_keys` for a what-if at `point` (see the module docstring)."""
    weak = [r for r in meta.get("weak_regions", []) if in_region(point, r)]
    warning = ("inside a known weak region of this model: " + "; ".join(str(r.get("note", "")) for r in weak)
               if weak else None)
    out = {}
    for quantity, err in error_keys.items():
        if not extrapolating:
            rec = _choose(meta.get("test_errors", {}), err, "on the held-out runs inside the trained ranges")
        elif meta.get("test_errors_outside"):
            rec = _choose(meta["test_errors_outside"], err, "on held-out runs outside the trained ranges")
        else:
            rec = Recommendation(None, "outside the trained ranges neither answer was validated")
        out[quantity] = Recommendation(rec.source, rec.reason, warning)
    return out


def as_dict(recs: Mapping[str, Recommendation]) -> dict[str, dict[str, Any]]:
    return {q: {"source": r.source, "reason": r.reason, "warning": r.warning} for q, r in recs.items()}


def trusted(meta: Mapping[str, Any], point: Mapping[str, float], extrapolating: bool,
            error_keys: Mapping[str, ErrorKey], warnings: list[str]) -> tuple[dict[str, dict[str, Any]], list[str]]:
    """(the recommendations of an answer as answer.json holds them, its warnings with a weak region's added)."""
    recs = recommend(meta, point, extrapolating, error_keys)
    return as_dict(recs), [*warnings, *sorted({r.warning for r in recs.values() if r.warning})]


def trust_label(rec: dict[str, Any] | None) -> str:
    return "-" if not rec or not rec.get("source") else ("GP" if rec["source"] == "gp" else "field model")


def trust_reasons(trusted: dict[str, dict[str, Any]], labels: dict[str, str]) -> list[str]:
    """One line per quantity: which answer to trust and why (`pretrained.trust`)."""
    if not trusted:
        return []
    return ["", "which answer to trust:"] + [f"  {labels.get(k, k)}: {trust_label(r)} ({r['reason']})"
                                            for k, r in trusted.items()]
