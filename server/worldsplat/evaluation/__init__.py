"""Evaluation against the world's exact ground truth: novel-track renders, refinement ablation (A-E), metrics.
See web/docs/refinement.md."""
from worldsplat.pipeline import JobCancelled as Cancelled  # one cancellation exception for every job stage

__all__ = ["Cancelled"]
