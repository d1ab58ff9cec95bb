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


@pytest.fixture(scope="session")
def cheap_tier_scene(tmp_path_factory):
    """``cheap_tier_scene(folder, duration)``: the example cantilever's mesh and co-rotational
    scene with a cheap tier (8 modes, the six axes, runs of ``duration`` s, 12 training cases)
    that misses its own check and is written all the same: for tests of the distribution, not
    its accuracy. Returns the scene's path in a fresh temporary ``folder``."""

    def make(folder: str, duration: float) -> pathlib.Path:
        d = tmp_path_factory.mktemp(folder)
        src = REPO / "models" / "cantilever"
        (d / "cantilever.msh").write_bytes((src / "cantilever.msh").read_bytes())
        head = (src / "scene_corotational.toml").read_text().split("[reduction.corotational]")[0]
        path = d / "scene.toml"
        path.write_text(
            head + f"[reduction.corotational]\nduration = {duration}\nevery = 5\norder = 8\n"
            'directions = "axes"\naccept_failed_check = true\n'
        )
        return path

    return make
