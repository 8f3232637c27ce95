"""Shared fixtures. Data in ../shared is used by path; tests that need it skip with the reason."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

SHARED = Path(__file__).resolve().parents[2] / "shared"
MESHES = SHARED / "meshes"
DATASET = SHARED / "datasets" / "nbv-regression-2019"
# What nbvdata publish requires beside the shards (nbvdata.datasets.about): as flags, and as the API takes it.
PUBLISHING = ["--license", "CC-BY-4.0", "--creator", "Lovelace, Ada", "--url", "https://example.org/{name}"]


def about():
    """``PUBLISHING`` as ``nbvdata.datasets.publish.publish`` takes it."""
    from nbvdata.datasets.about import load_about

    return load_about(license="CC-BY-4.0", creators=["Lovelace, Ada"], url="https://example.org/{name}")


def need(path: Path) -> Path:
    """Skip the calling test, saying which folder is missing, when ``path`` does not exist."""
    if not path.exists():
        pytest.skip(f"{path} is absent (shared data is not part of a clone of this repository)")
    return path


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)
