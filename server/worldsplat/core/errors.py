"""The one cancellation exception: every stage of every job (scene generation, rendering, refinement, evaluation)
raises it when its `cancelled()` callback says so, and the job queue recognises it by type."""

from __future__ import annotations


class Cancelled(Exception):
    """Raised between stages (or frames) when the caller's `cancelled()` returns True."""


def check(cancelled, message: str = "cancelled") -> None:
    """Raise Cancelled when the callback `cancelled` (or None) says so."""
    if cancelled is not None and cancelled():
        raise Cancelled(message)
