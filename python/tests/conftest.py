import pathlib

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def repo():
    return REPO


@pytest.fixture(scope="session")
def cantilever_path():
    return REPO / "models" / "cantilever" / "model.crokf"


@pytest.fixture(scope="session")
def meniscus_path():
    return REPO / "models" / "meniscus" / "model.crokf"
