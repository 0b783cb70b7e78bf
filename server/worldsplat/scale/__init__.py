"""Beyond one machine: the dataset and scene batches as Ray tasks (`dataset`, `batch`, `ray_runner`) and generated
or ground-truth clips in the nuScenes layout (`nuscenes`). Ray is imported only when a run asks for it."""
