"""``isp profiles``: the lens profiles, each with the identity it matches and its model."""

from __future__ import annotations

import argparse
import json

EPILOG = """\
examples:
  isp profiles
  isp profiles --json

A profile is a TOML file in the user folder ($ISP_PROFILES, else
~/.config/phone-isp/profiles), e.g. my_lens.toml:
  schema = "profile/v1"
  name = "my_lens"
  model = "my_lens.int8.onnx"        # relative to the profile file
  [match]
  LensModel = "ACME 4.2mm f/1.8"     # exact, or a glob ("ACME 4.2mm*")
  UniqueCameraModel = "ACME Phone*"  # every key given must match
The correction stage runs the model of the most specific matching profile and
nothing where none matches (`isp info FILE` says which, or why not).
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp profiles``."""
    p.description = ("List the lens profiles: each pairs a lens identity (UniqueCameraModel, Make, Model, "
                     "LensModel) with its correction model. They come packaged, from the user folder, or "
                     "from other packages' 'isp.profiles' entry points; a profile file that cannot be read "
                     "is listed with the reason.")
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("--json", action="store_true", help="print the list as JSON")


def run(args: argparse.Namespace) -> int:
    """Print every profile (name, origin, identity keys, model) and every
    unreadable one with its reason; 0 even then (a broken profile stops no
    render)."""
    from isp.profiles import broken_profiles, list_profiles, profile_origin, profile_source, user_folders

    profiles = list_profiles()
    broken = broken_profiles()
    folders = [str(f) for f in user_folders()]
    if args.json:
        print(json.dumps({
            "profiles": [{**p.as_dict(), "origin": profile_origin(n), "from": profile_source(n)}
                         for n, p in profiles.items()],
            "broken": broken, "user_folders": folders}, indent=2))
        return 0
    for name, p in profiles.items():
        print(f"{name:<15s} {profile_origin(name):<9s} {p.describe_match()}")
        print(f"{'':<15s} model {p.model}")
        for what, path in (("with a module's calibration", p.device_model), ("descriptor basis", p.basis),
                           ("module calibration", p.device)):
            if path is not None:
                print(f"{'':<15s} {what} {path}")
        if p.description:
            print(f"{'':<15s} {p.description}")
    if not profiles:
        print("no profiles: every file is rendered without correction")
    for where, reason in broken.items():
        print(f"unreadable profile {where}: {reason}")
    print(f"user folder{'s' if len(folders) > 1 else ''}: {', '.join(folders)} (set ISP_PROFILES to change)")
    return 0
