"""Layer 1, the core: what every other layer shares and that depends on nothing of the package. Cameras and the rig
(`camera`), the scenario schema and presets (`scenario`), atomic file writes (`io`), image metrics (`metrics`),
videos and mosaics (`video`), the cancellation exception (`errors`), the limits shared with the viewer (`limits`)
and the one place that knows where the source checkout's folders are (`paths`)."""
