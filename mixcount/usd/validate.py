"""Validate a stage with USD's own checkers; used by tests and ``mixcount compose --stage-only --check``.

usd-core 26.x no longer ships ``pxr.UsdUtils.ComplianceChecker`` (the Python module behind the old
``usdchecker``); its rules moved into the C++ ``UsdValidation`` framework, which also adds UsdPhysics
checks (colliders, rigid bodies). :func:`validate_stage` runs every registered validator except the
USDZ-package ones and, where the old ComplianceChecker still exists (older usd-core), that too.
"""

from __future__ import annotations

from pathlib import Path

USDZ_ONLY = ("UsdzValidators",)


def validate_stage(path: str | Path) -> list[str]:
    """Error messages from USD's validators for the stage at ``path`` (empty list = clean)."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(path))
    if stage is None:
        return [f"cannot open stage {path}"]
    errors: list[str] = []
    try:
        from pxr import UsdValidation
    except ImportError:  # pragma: no cover - older usd-core
        UsdValidation = None  # type: ignore[assignment]
    if UsdValidation is not None:
        registry = UsdValidation.ValidationRegistry()
        validators = []
        for meta in registry.GetAllValidatorMetadata():
            if meta.isSuite or any(k in USDZ_ONLY for k in meta.GetKeywords()):
                continue
            v = registry.GetOrLoadValidatorByName(meta.name)
            if v is not None:
                validators.append(v)
        context = UsdValidation.ValidationContext(validators)
        for err in context.Validate(stage):
            if err.GetType() == UsdValidation.ValidationErrorType.Error:
                errors.append(f"{err.GetName()}: {err.GetMessage()}")
    try:  # pragma: no cover - only on usd-core versions that still have it
        from pxr.UsdUtils.complianceChecker import ComplianceChecker  # type: ignore[import-not-found]
    except ImportError:
        return errors
    checker = ComplianceChecker(arkit=False, skipARKitRootLayerCheck=True, rootPackageOnly=False)
    checker.CheckCompliance(str(path))
    errors.extend(checker.GetErrors())
    return errors


def validation_report(path: str | Path) -> dict[str, list[str]]:
    """Every finding (errors and warnings) by type name, for docs and debugging."""
    from pxr import Usd, UsdValidation

    stage = Usd.Stage.Open(str(path))
    registry = UsdValidation.ValidationRegistry()
    validators = [registry.GetOrLoadValidatorByName(m.name) for m in registry.GetAllValidatorMetadata()
                  if not m.isSuite and not any(k in USDZ_ONLY for k in m.GetKeywords())]
    out: dict[str, list[str]] = {}
    for err in UsdValidation.ValidationContext([v for v in validators if v]).Validate(stage):
        out.setdefault(str(err.GetType()), []).append(f"{err.GetName()}: {err.GetMessage()}")
    return out
