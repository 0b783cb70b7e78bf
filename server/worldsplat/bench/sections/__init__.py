"""One module per knob; each exposes `run(quick: bool) -> Section`."""
