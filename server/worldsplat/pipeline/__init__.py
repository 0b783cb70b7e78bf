"""Layer 4, the pipeline: scenario -> 4D Gaussian scene in every mode (`scene`, paper eq. 3 via
`gaussians.aggregate_4d`), the networks' inference glue and model loading (`inference`, `onnx`), their condition
arrays (`conditions`), the one track renderer (`render`) and refinement of shifted tracks (`refine`)."""
