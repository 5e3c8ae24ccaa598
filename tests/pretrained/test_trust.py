"""Which answer to trust, on constructed cases: the lower validated error inside the trained ranges, the errors
recorded outside them when there are some, no recommendation where neither was validated, a warning inside a
known weak region."""

from __future__ import annotations

from neuraldem.pretrained.trust import ErrorKey, recommend

KEYS = {"t95": ErrorKey("t95_pct", " %"), "regime": ErrorKey("regime_accuracy", higher_is_better=True)}
META = {"test_errors": {"gp": {"t95_pct": 5.0, "regime_accuracy": 1.0},
                        "field model": {"t95_pct": 4.0, "regime_accuracy": 0.8}}}


def test_inside_the_ranges_the_lower_error_wins_per_quantity():
    recs = recommend(META, {"alpha": 30.0}, extrapolating=False, error_keys=KEYS)
    assert recs["t95"].source == "field model" and "GP 5 %, field model 4 %" in recs["t95"].reason
    assert recs["regime"].source == "gp" and "higher validated accuracy" in recs["regime"].reason
    assert recs["t95"].warning is None


def test_outside_the_ranges_only_errors_validated_outside_count():
    recs = recommend(META, {"alpha": 70.0}, extrapolating=True, error_keys=KEYS)
    assert recs["t95"].source is None and "neither answer was validated" in recs["t95"].reason
    outside = {**META, "test_errors_outside": {"gp": {"t95_pct": 32.0}, "field model": {"t95_pct": 3.8}}}
    recs = recommend(outside, {"alpha": 70.0}, extrapolating=True, error_keys=KEYS)
    assert recs["t95"].source == "field model" and "outside the trained ranges" in recs["t95"].reason
    assert recs["regime"].source is None  # no regime accuracy recorded outside


def test_a_known_weak_region_warns_with_its_note():
    meta = {**META, "weak_regions": [{"parameters": {"alpha": [40.0, 50.0]}, "note": "mass-flow index compressed"}]}
    inside = recommend(meta, {"alpha": 45.0}, extrapolating=False, error_keys=KEYS)
    assert inside["t95"].warning == "inside a known weak region of this model: mass-flow index compressed"
    assert recommend(meta, {"alpha": 30.0}, extrapolating=False, error_keys=KEYS)["t95"].warning is None
