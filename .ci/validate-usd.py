#!/usr/bin/env python3
"""Opens USD stages with Pixar's USD (PyPI usd-core) and runs every registered validator.

Usage: python3 .ci/validate-usd.py FILE.usda [FILE...]
Exits 1 if a stage fails to open or any validator reports an error, 2 if pxr is missing.
"""
import sys

try:
    from pxr import Usd, UsdValidation
except ImportError as e:  # pragma: no cover
    print(f"pxr not importable ({e}): pip install usd-core", file=sys.stderr)
    sys.exit(2)


def validate(path):
    stage = Usd.Stage.Open(path)
    if stage is None:
        print(f"{path}: failed to open")
        return 1
    registry = UsdValidation.ValidationRegistry()
    validators = registry.GetOrLoadAllValidators()
    context = UsdValidation.ValidationContext(validators)
    errors = context.Validate(stage)
    counts = {}
    bad = 0
    for err in errors:
        kind = err.GetType()
        counts[str(kind)] = counts.get(str(kind), 0) + 1
        print(f"  {kind} {err.GetName()}: {err.GetMessage()}")
        if kind == UsdValidation.ValidationErrorType.Error:
            bad += 1
    samples = {
        str(p.GetPath()): len(p.GetAttribute("points").GetTimeSamples())
        for p in stage.Traverse()
        if p.GetTypeName() == "Mesh"
    }
    print(
        f"{path}: {len(validators)} validators, {bad} errors, issues by type {counts}; "
        f"timeCodesPerSecond {stage.GetTimeCodesPerSecond()}, "
        f"time codes {stage.GetStartTimeCode()}..{stage.GetEndTimeCode()}, "
        f"points time samples {samples}"
    )
    return 1 if bad else 0


if __name__ == "__main__":
    if len(sys.argv) < 2:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    sys.exit(max(validate(p) for p in sys.argv[1:]))
