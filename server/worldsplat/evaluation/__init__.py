"""Evaluation against the world's exact ground truth: the shipped models (`models`) and the novel-view refinement
ablation A-E (`nvs`). See web/docs/models.md and web/docs/refinement.md."""
