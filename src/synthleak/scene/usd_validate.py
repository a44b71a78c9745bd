"""Check a stage with every ``pxr.UsdValidation`` validator."""

from __future__ import annotations

from pathlib import Path

from pxr import Tf, UsdValidation

from synthleak.core.usd_read import open_stage


def validate_stage(path: Path) -> list[str]:
    """Error messages of all ``pxr.UsdValidation`` validators (a validator that itself raises is skipped)."""
    stage = open_stage(Path(path))
    messages: list[str] = []
    for validator in UsdValidation.ValidationRegistry().GetOrLoadAllValidators():
        name = validator.GetMetadata().name
        try:
            errors = UsdValidation.ValidationContext([validator]).Validate(stage)
        except Tf.ErrorException:
            continue
        for error in errors:
            if error.GetType() == UsdValidation.ValidationErrorType.Error:
                messages.append(f"{path}: {name}: {error.GetMessage()}")
    return messages
