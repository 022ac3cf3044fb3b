"""benchmarks/loop_suite.py (kind: property): a case is the same on every
run (so the suite resumes in parts), its effects come from the ranges and
have injections, and the summary counts right, missed and false effects."""

import pytest

from benchmarks import loop_suite
from calibration.simulate.injected import INJECTIONS

pytestmark = pytest.mark.property


def test_cases_are_fixed_and_within_their_ranges():
    cases = [loop_suite.draw_case(k) for k in range(24)]
    assert cases == [loop_suite.draw_case(k) for k in range(24)]
    assert [c["lens"] for c in cases[:4]] == ["e1", "e2", "e9", "e11"]
    assert {len(c["effects"]) for c in cases} == {0, 1, 2}
    for c in cases:
        for e, p in c["effects"].items():
            assert e in INJECTIONS and set(p) == set(loop_suite.RANGES[e])
            for k, v in p.items():
                lo, hi = loop_suite.RANGES[e][k]
                assert lo - 1e-4 <= v <= hi + 1e-4


def test_summary_counts_what_was_named():
    def case(put, added):
        c = {"effects": {e: {} for e in put}, "effects_added": added, "right": sorted(set(put) & set(added)),
             "missed": sorted(set(put) - set(added)), "false": sorted(set(added) - set(put)),
             "after_over_floor": 1.1, "wall_s": 100.0}
        return c

    s = loop_suite.summarise([case(["sharpening"], ["sharpening"]), case(["pixel_crosstalk", "sharpening"],
                                                                          ["sharpening", "focus_shift"]),
                              case([], []), case([], ["veiling_glare"])])
    assert s["per_effect"]["sharpening"] == {"put_in": 2, "named": 2}
    assert s["per_effect"]["pixel_crosstalk"] == {"put_in": 1, "named": 0}
    assert s["false_additions"] == {"focus_shift": 1, "veiling_glare": 1}
    assert s["clean_cases"] == 2 and s["clean_given_an_effect"] == 1 and s["all_right"] == 2
    assert s["kept"] == {"effects": 4, "put_in": 2, "at_z3": 0, "at_z3_put_in": 0}


def test_the_kept_effects_are_counted_with_their_confidence():
    """Of the effects the loop kept, how many were put in, overall and at
    z ≥ 3 (records without z count only overall)."""
    def case(put, added, z):
        return {"effects": {e: {} for e in put}, "effects_added": added,
                "confidence": {e: {"z": v} for e, v in zip(added, z) if v is not None},
                "right": [], "missed": [], "false": [], "after_over_floor": 1.0, "wall_s": 1.0}

    s = loop_suite.summarise([case(["sharpening"], ["sharpening", "veiling_glare"], [5.0, 3.5]),
                              case(["pixel_crosstalk"], ["pixel_crosstalk"], [2.0]),
                              case([], ["motion_blur"], [None])])
    assert s["kept"] == {"effects": 4, "put_in": 2, "at_z3": 2, "at_z3_put_in": 1}


def test_a_focus_shift_is_judged_by_the_defocus_the_loop_reports():
    """A focus shift is named where the reported defocus lies within 30 %
    of the shift (or 1.5 µm) of the truth; without a shift, a defocus off by
    more than the smallest shift put in is a false focus shift."""
    put = {"focus_shift": {"dz_um": 8.0}, "sharpening": {"gain": 0.5, "sigma_px": 1.0}}
    assert loop_suite.judged(put, ["sharpening"], 9.9, 8.3) == ({"focus_shift", "sharpening"}, set())
    assert loop_suite.judged(put, [], 5.0, 8.3) == (set(), set())              # 3.3 µm off: more than 30 %
    assert loop_suite.judged(put, ["focus_shift"], None, 8.3) == ({"focus_shift"}, set())
    clean = {"pixel_crosstalk": {"leak": 0.03}}
    assert loop_suite.judged(clean, [], 4.8, 0.1) == (set(), {"focus_shift"})
    assert loop_suite.judged(clean, ["pixel_crosstalk"], 3.9, 0.1) == ({"pixel_crosstalk"}, set())
    assert loop_suite.judged({}, ["veiling_glare"], None, 0.0) == (set(), {"veiling_glare"})


def test_the_true_defocus_is_the_shift_put_in_on_a_refocused_device():
    """A refocused device is at the design's own focus (its best focus
    moved by the last gap, exactly), so its true defocus is the shift's."""
    from calibration.optics.io import read_lens
    from calibration.simulate.device import device_lens

    path = loop_suite.PHONE / f"{loop_suite.LENSES['e9']}.zmx"
    if not path.is_file():
        pytest.skip(f"{path} absent (../shared/data)")
    device, _ = device_lens(read_lens(path), "random", seed=3)
    assert loop_suite.true_defocus_um(device, {}) == pytest.approx(0.0, abs=1e-6)
    assert loop_suite.true_defocus_um(device, {"focus_shift": {"dz_um": 6.5}}) == pytest.approx(6.5, abs=1e-6)


def test_cases_past_the_registry_put_in_one_effect_outside_it():
    from calibration.simulate.injected import OUTSIDE

    extra = [loop_suite.draw_case(loop_suite.REGISTRY_CASES + j) for j in range(len(loop_suite.OUTSIDE_RANGES))]
    assert [list(c["effects"]) for c in extra] == [[e] for e in loop_suite.OUTSIDE_RANGES]
    for c in extra:
        for e, p in c["effects"].items():
            assert e in OUTSIDE and set(p) == set(loop_suite.OUTSIDE_RANGES[e])
    rows = [{"effects": {"jpeg": {}}, "effects_added": [], "right": [], "missed": [], "false": [],
             "after_over_floor": 1.3, "wall_s": 1.0},
            {"effects": {"haze": {}}, "effects_added": ["veiling_glare"], "right": [], "missed": [],
             "false": ["veiling_glare"], "after_over_floor": 1.1, "wall_s": 1.0}]
    s = loop_suite.summarise(rows)
    assert s["outside_registry"]["jpeg"] == {"put_in": 1, "nothing_added": 1}
    assert s["outside_registry"]["haze"] == {"put_in": 1, "nothing_added": 0}
    assert s["all_right"] == 1 and s["false_additions"] == {"veiling_glare": 1}
