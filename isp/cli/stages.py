"""``isp stages``: the registered stages, or one stage's parameters and documentation."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp stages``."""
    p.description = ("List every stage the registry knows: built-in ones and those other installed "
                     "packages add through the 'isp.stages' entry point group. With a NAME, show its "
                     "parameters and documentation.")
    p.epilog = "examples:\n  isp stages\n  isp stages demosaic"
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("name", nargs="?", help="a stage to describe")


def run(args: argparse.Namespace) -> int:
    """Print the stage list, or the stage ``args.name``."""
    from isp.registry import broken_stages, get_stage_class, list_stages, stage_origin
    from isp.stage import stage_parameters

    if args.name:
        cls = get_stage_class(args.name)
        doc = (cls.__doc__ or "").strip()
        print(f"{args.name}  ({stage_origin(args.name)})")
        print(f"  consumes: {', '.join(d.value for d in cls.consumes)}")
        print(f"  produces: {cls.produces.value if getattr(cls, 'produces', None) else 'same as input'}")
        params = stage_parameters(cls)
        if params is not None:
            print("  parameters:")
            for name, default, tp in params:
                print(f"    {name} = {default!r}   [{tp}]")
        print()
        print(doc)
        return 0
    for name, cls in list_stages().items():
        summary = (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""
        cons = "|".join(d.value for d in getattr(cls, "consumes", ()))
        prod = cls.produces.value if getattr(cls, "produces", None) else "same"
        print(f"{name:<15s} {cons} -> {prod}")
        print(f"{'':<15s} {summary}  [{stage_origin(name)}]")
    for name, err in broken_stages().items():
        print(f"{name:<15s} FAILED TO LOAD: {err}")
    return 0
