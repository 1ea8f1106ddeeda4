"""User-facing errors: every one says what is wrong and what to do about it."""

from __future__ import annotations


class StringsBenchError(Exception):
    """An error caused by input or environment, shown to the user without a traceback.

    `hint` tells the user what to do; the CLI prints it on its own line.
    """

    def __init__(self, message: str, hint: str | None = None):
        super().__init__(message)
        self.message = message
        self.hint = hint

    def __str__(self) -> str:
        return self.message if not self.hint else f"{self.message}\n  hint: {self.hint}"


class DatasetError(StringsBenchError):
    """A scene folder, COLMAP model, image or mask is missing or malformed."""


class OCRError(StringsBenchError):
    """An OCR backend is unavailable or failed."""


class TrainingError(StringsBenchError):
    """Training diverged (NaN/Inf) or was misconfigured."""
