"""The folders of the source checkout that the package uses when run from it (the page, the docs, the shared test
vectors, git-ignored run and cache folders). One place finds the checkout: `$WORLDSPLAT_ROOT`, else the nearest
folder above this file that holds both `pyproject.toml` and `web/`, else the working directory. Every function
that needs one of these folders takes it as an argument and defaults to the function here."""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path


@lru_cache(maxsize=1)
def source_root() -> Path:
    env = os.environ.get("WORLDSPLAT_ROOT")
    if env:
        return Path(env).resolve()
    for d in Path(__file__).resolve().parents:
        if (d / "pyproject.toml").is_file() and (d / "web").is_dir():
            return d
    return Path.cwd()


def web_dir() -> Path:
    """The page (served by the playground) and its docs (`docs/`)."""
    return source_root() / "web"


def docs_dir() -> Path:
    return web_dir() / "docs"


def vectors_dir() -> Path:
    """The shared test vectors (tests/vectors)."""
    return source_root() / "tests" / "vectors"


def runs_dir() -> Path:
    """Git-ignored training and evaluation outputs."""
    return source_root() / "runs"


def cache_dir() -> Path:
    """The playground's default artifact store (`$WORLDSPLAT_CACHE` overrides it in `worldsplat serve`)."""
    return source_root() / "cache"
