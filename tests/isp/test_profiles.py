"""Lens profiles: reading profile files, matching a capture's identity
(exact, glob, every key, the most specific), the user folder, plug-ins, and
broken profiles reported without stopping the others (kind: property)."""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

import pytest

from isp.errors import ConfigError, InputError
from isp.meta import CameraMeta
from isp.profiles import (
    Profile,
    broken_profiles,
    describe_identity,
    get_profile,
    identity,
    list_profiles,
    match_profile,
    profile_origin,
    read_profile,
    register_profile,
    reload_profiles,
)

pytestmark = pytest.mark.property

#: what a plug-in's entry point names in the plug-in test (a profile file's path)
PLUGIN_PROFILE = None


def write_profile(folder: Path, stem: str, match: str, *, model: str = "m.onnx", extra: str = "") -> Path:
    """A profile file ``stem.toml`` in ``folder`` with a ``[match]`` body and
    a dummy model file beside it."""
    (folder / model).write_bytes(b"not read by the registry")
    path = folder / f"{stem}.toml"
    path.write_text(f'schema = "profile/v1"\nmodel = "{model}"\n{extra}\n[match]\n{match}\n')
    return path


# -- the packaged profile --------------------------------------------------------------

def test_packaged_profile_names_the_e9_lens_and_its_model(user_folder):
    """The default phone lens's model runs on its captures (nominal and
    perturbed samples, as the simulator names them) and on nothing else:
    not another embodiment of the same patent, not a longer name, not a
    file without LensModel."""
    p = get_profile("e9")
    assert profile_origin("e9") == "packaged"
    assert p.model.name == "e9_default.int8.onnx" and p.model.is_file()
    for lens in ("US-12210142-B2-e9", "US-12210142-B2-e9 (perturbed)", "  US-12210142-B2-e9 "):
        assert match_profile({"LensModel": lens}).profile is p, lens
    for lens in ("US-12210142-B2-e2", "US-12210142-B2-e99", "US-12210142-B2", "us-12210142-b2-e9", ""):
        assert match_profile({"LensModel": lens}).profile is None, lens


# -- matching --------------------------------------------------------------------------

def _p(name, **match):
    return Profile(name, match, f"{name}.onnx")


def test_exact_glob_any_pattern_and_every_key():
    ps = {"a": _p("a", Make="GoPro", Model=["HERO6*", "FUSION"])}
    assert match_profile({"Make": "GoPro", "Model": "HERO6 Black"}, ps).profile.name == "a"
    assert match_profile({"Make": "GoPro", "Model": "FUSION"}, ps).profile.name == "a"
    assert match_profile({"Make": "GoPro", "Model": "FUSION 2"}, ps).profile is None   # exact is exact
    assert match_profile({"Make": "Canon", "Model": "FUSION"}, ps).profile is None    # every key
    assert match_profile({"Model": "FUSION"}, ps).profile is None                     # absent = ""
    assert match_profile({"Make": "gopro", "Model": "FUSION"}, ps).profile is None    # case-sensitive
    star = {"s": _p("s", LensModel="*")}
    assert match_profile({"Make": "X"}, star).profile.name == "s"                     # "*" matches ""


def test_the_most_specific_profile_wins_and_all_matching_are_named():
    ps = {"lens-glob": _p("lens-glob", LensModel="ACME*"),
          "lens": _p("lens", LensModel="ACME 4.2"),
          "device": _p("device", LensModel="ACME*", UniqueCameraModel="ACME Phone 7"),
          "longer-glob": _p("longer-glob", LensModel="ACME 4*")}
    m = match_profile({"LensModel": "ACME 4.2", "UniqueCameraModel": "ACME Phone 7"}, ps)
    # two keys beat one; then exact beats glob; then more literal characters
    assert [p.name for p in m.matching] == ["device", "lens", "longer-glob", "lens-glob"]
    reason = m.reason()
    assert reason.startswith("profile 'device' (LensModel 'ACME 4.2', UniqueCameraModel 'ACME Phone 7')")
    assert "the most specific of 4 matching: device, lens, longer-glob, lens-glob" in reason


def test_no_match_says_what_the_file_is_and_what_profiles_there_are():
    ps = {"e9": _p("e9", LensModel="US-12210142-B2-e9")}
    gopro = CameraMeta(make="GoPro", model="HERO6 Black", unique_camera_model="GoPro HERO6 Black")
    m = match_profile(gopro, ps)
    assert m.profile is None and m.matching == ()
    assert m.reason() == ("no profile for UniqueCameraModel 'GoPro HERO6 Black', Make 'GoPro', "
                          "Model 'HERO6 Black', no LensModel; profiles: e9 (LensModel 'US-12210142-B2-e9')")
    m = match_profile(CameraMeta(make="ACME", lens="ACME 4.2"), ps)
    assert m.reason().startswith("no profile for LensModel 'ACME 4.2' (Make 'ACME'); profiles: e9 ")
    assert "profiles: none" in match_profile(gopro, {}).reason()


def test_identity_reads_the_four_tags_of_camera_meta():
    meta = CameraMeta(make="LG Mobile", model="LG-H815", unique_camera_model="LG-H815", lens="4.4 mm f/1.8 ")
    ident = identity(meta)
    assert ident == {"UniqueCameraModel": "LG-H815", "Make": "LG Mobile", "Model": "LG-H815",
                     "LensModel": "4.4 mm f/1.8"}
    assert describe_identity(identity(CameraMeta())) == \
        "no UniqueCameraModel, no Make, no Model, no LensModel"


@pytest.mark.parametrize("match, error", [
    ({}, "at least one of"),
    ({"Lens": "x"}, "unknown identity key 'Lens'; valid: UniqueCameraModel, Make, Model, LensModel"),
    ({"Make": 3}, "Make must be a string or a list of strings"),
    ({"Make": []}, "Make must be a string or a list of strings"),
])
def test_a_bad_profile_in_code_is_refused_naming_the_key(match, error):
    with pytest.raises(ConfigError, match=error.replace("(", r"\(")):
        Profile("p", match, "m.onnx")


# -- files, the user folder, plug-ins --------------------------------------------------

def test_user_profile_is_read_relative_to_its_file_and_listed(user_folder):
    path = write_profile(user_folder, "acme", 'LensModel = "ACME 4.2"', extra='name = "acme-4.2"')
    profiles = list_profiles()
    assert {"e9", "acme-4.2"} <= set(profiles)
    p = profiles["acme-4.2"]
    assert p.model == user_folder / "m.onnx" and p.source == str(path)
    assert profile_origin("acme-4.2") == "user" and broken_profiles() == {}
    assert match_profile(CameraMeta(lens="ACME 4.2")).profile is p


@pytest.mark.parametrize("text, reason", [
    ("model = \n", "not a TOML profile"),
    ('schema = "profile/v9"\nmodel = "m.onnx"\n[match]\nMake = "x"\n', "schema 'profile/v9'"),
    ('model = "m.onnx"\nlens = "x"\n[match]\nMake = "x"\n', "unknown key(s) lens"),
    ('model = "m.onnx"\n', "a profile needs match"),
    ('model = "absent.onnx"\n[match]\nMake = "x"\n', "absent.onnx' not found"),
    ('model = "m.onnx"\n[match]\nLens = "x"\n', "unknown identity key 'Lens'"),
    ('model = "m.onnx"\ndevice_model = "absent.onnx"\n[match]\nMake = "x"\n', "device model file"),
    ('model = "m.onnx"\nbasis = "absent.npz"\n[match]\nMake = "x"\n', "basis file"),
    ('model = "m.onnx"\nbasis = 3\n[match]\nMake = "x"\n', "'basis' must be a file name"),
])
def test_a_broken_user_profile_is_reported_in_one_line_and_the_others_stay(user_folder, text, reason):
    (user_folder / "m.onnx").write_bytes(b"x")
    write_profile(user_folder, "good", 'Make = "ACME"')
    bad = user_folder / "bad.toml"
    bad.write_text(text)
    with pytest.raises(InputError) as e:
        read_profile(bad)
    assert str(e.value).startswith(str(bad)) and reason in str(e.value) and "\n" not in str(e.value)
    broken = broken_profiles()
    assert list(broken) == [str(bad)] and reason in broken[str(bad)]
    assert {"e9", "good"} <= set(list_profiles())
    m = match_profile(CameraMeta(make="ACME"))
    assert m.profile.name == "good" and "1 profile(s) unreadable (see `isp profiles`)" in m.reason()


def test_equally_specific_profiles_rank_user_over_code_over_packaged(user_folder):
    write_profile(user_folder, "mine", 'LensModel = "US-12210142-B2-e9"')
    register_profile(_p("in-code", LensModel="US-12210142-B2-e9"))
    try:
        m = match_profile({"LensModel": "US-12210142-B2-e9"})
        assert [p.name for p in m.matching] == ["mine", "in-code", "e9"]
    finally:
        from isp.profiles import PROFILES

        PROFILES.remove("in-code")


def test_plugin_profiles_come_through_the_entry_point_group(user_folder, monkeypatch):
    """A distribution's ``isp.profiles`` entry point names a profile file;
    one that fails to load is recorded with the reason."""
    global PLUGIN_PROFILE
    PLUGIN_PROFILE = write_profile(user_folder.parent, "plug", 'Make = "Plug"')
    real = metadata.entry_points
    extra = [metadata.EntryPoint("plug", f"{__name__}:PLUGIN_PROFILE", "isp.profiles"),
             metadata.EntryPoint("gone", f"{__name__}:NO_SUCH_NAME", "isp.profiles")]

    def entry_points(**kw):
        found = list(real(**kw))
        return found + extra if kw.get("group") == "isp.profiles" else found

    monkeypatch.setattr(metadata, "entry_points", entry_points)
    try:
        reload_profiles()
        assert profile_origin("plug") == "plug-in" and profile_origin("e9") == "packaged"
        assert match_profile({"Make": "Plug"}).profile.name == "plug"
        assert "NO_SUCH_NAME" in broken_profiles()["gone"]
    finally:
        monkeypatch.undo()
        reload_profiles()
