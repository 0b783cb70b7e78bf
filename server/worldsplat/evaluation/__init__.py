"""Evaluation against the world's exact ground truth: novel-track renders, refinement ablation (A-E), metrics.
See web/docs/refinement.md."""


class Cancelled(Exception):
    """Raised between stages when a job's `cancelled()` callback returns True."""
