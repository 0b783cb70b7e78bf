"""The playground server: FastAPI app (app.py), background jobs (jobs.py), artifact cache (cache.py), `worldsplat serve`."""
