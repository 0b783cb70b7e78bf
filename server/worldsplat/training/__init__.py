"""Layer 5, training: the training data (`data`), the one training loop every model shares (`loop`: checkpoint,
resume, schedule, clipping, progress), the enhancer's pairs and phases (`pairs`, `enhancer`) and shipping trained
weights (`ship`). Imports the pipeline and everything below it."""
