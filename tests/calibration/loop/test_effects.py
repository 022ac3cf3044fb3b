"""The loop's effect registry (calibration.loop.effects), kind: property:
the built-in effects are listed, an unknown name is refused, and an effect
registered from outside is listed and created by name."""

import pytest

from isp.errors import ConfigError

from calibration.loop.effects import Effect, create_effect, list_effects, register_effect

pytestmark = pytest.mark.property


def test_registry_lists_the_required_effects():
    have = set(list_effects())
    assert {"sensor_tilt", "focus_shift", "field_curvature", "pixel_crosstalk", "lateral_ca", "sharpening",
            "veiling_glare"} <= have
    with pytest.raises(ConfigError, match="unknown effect 'nope'; valid: field_curvature, focus_shift"):
        create_effect("nope")


def test_plugin_effect_via_register():
    @register_effect
    class Nothing(Effect):
        """Does nothing."""

        name = "test_nothing"
        names, units, x0, lower, upper, scale = ("a",), ("—",), (0.0,), (-1.0,), (1.0,), (0.1,)

    from calibration.loop import effects
    try:
        assert "test_nothing" in list_effects()
        assert create_effect("test_nothing").transfer([0.0], None) is None
    finally:
        effects.EFFECTS.remove("test_nothing")
