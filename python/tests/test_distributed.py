"""The tier's training on Dask (``crokf.distributed``): the model is byte-identical to a
compile in one process, and a worker killed with a case in flight loses only that case.

Scene: the example cantilever's mesh and tier with a short training plan (the six axes,
0.2 s runs: 12 cases), so that the test runs in seconds on two local workers.
"""

import os
import signal
import threading
import time

import pytest

distributed = pytest.importorskip("distributed")

import crokf  # noqa: E402
from crokf.distributed import compile_distributed, main  # noqa: E402


@pytest.fixture(scope="module")
def scene(repo, tmp_path_factory):
    d = tmp_path_factory.mktemp("dask")
    src = repo / "models" / "cantilever"
    (d / "cantilever.msh").write_bytes((src / "cantilever.msh").read_bytes())
    head = (src / "scene_corotational.toml").read_text().split("[reduction.corotational]")[0]
    text = head + (
        "[reduction.corotational]\nduration = 0.2\nevery = 5\norder = 8\n"
        'directions = "axes"\n'
        # A cheap tier (8 modes, 0.2 s runs) that misses its own check: these tests are about
        # the distribution, not its accuracy.
        "accept_failed_check = true\n"
    )
    path = d / "scene.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def reference(scene):
    model, _ = crokf.compile(str(scene), report=False)
    return model.to_bytes()


@pytest.fixture(scope="module")
def client():
    from distributed import Client, LocalCluster

    cluster = LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    )
    c = Client(cluster)
    yield c
    c.close()
    cluster.close()


def test_the_model_is_byte_identical_to_a_compile_in_one_process(scene, reference, client, tmp_path):
    out = tmp_path / "model.crokf"
    cases = crokf.training_cases(str(scene))
    assert len(cases) == 12
    model, _ = compile_distributed(scene, out, client=client, report=False, progress=False)
    assert out.read_bytes() == reference
    assert model.to_bytes() == reference
    # The default cache (OUTPUT.cases) is removed after a successful compile.
    assert not (tmp_path / "model.crokf.cases").exists()


def test_a_killed_worker_loses_only_its_case(scene, reference, client, tmp_path):
    cache = tmp_path / "cache"
    cases = crokf.training_cases(str(scene))
    seen = {}

    def kill_one_busy_worker():
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            stored = list(cache.glob("*.case")) if cache.is_dir() else []
            busy = {w: k for w, k in client.processing().items() if k}
            if stored and busy:
                seen.update({p.name: p.stat().st_mtime_ns for p in stored})
                pids = client.run(os.getpid)
                worker = next(iter(busy))
                seen["killed"] = (worker, list(busy[worker]))
                os.kill(pids[worker], signal.SIGKILL)
                return
            time.sleep(0.005)

    killer = threading.Thread(target=kill_one_busy_worker)
    killer.start()
    model, _ = compile_distributed(scene, client=client, cache=cache, report=False, progress=False)
    killer.join()
    assert "killed" in seen, "no worker was caught with a case in flight"
    assert model.to_bytes() == reference
    files = sorted(p.name for p in cache.glob("*.case"))
    assert files == sorted(f"{c[1]}.case" for c in cases)
    # The cases gathered before the kill were not run again.
    for name, mtime in seen.items():
        if name != "killed":
            assert (cache / name).stat().st_mtime_ns == mtime, name
    assert not list(cache.glob(".*.tmp")), "no temporary left"


def test_the_command_line_refuses_a_scene_without_a_tier(repo, tmp_path, capsys):
    code = main([str(repo / "models" / "cantilever" / "scene.toml"), "-o", str(tmp_path / "m.crokf")])
    assert code == 1
    err = capsys.readouterr().err
    assert "crokf.distributed: error:" in err and "[reduction.corotational]" in err
    assert not (tmp_path / "m.crokf").exists()
    assert not (tmp_path / "m.crokf.cases").exists()


def test_a_damaged_case_file_is_run_again_on_the_cluster(scene, reference, client, tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    compile_distributed(scene, client=client, cache=cache, report=False, progress=False)
    status = crokf.training_case_status(str(scene), str(cache))
    assert [why for _, _, why in status] == [None] * len(status)
    # One file cut short, one deleted: both named, both run again on the cluster (every case
    # is usable when the compile starts, so it computes none itself).
    index, identity, _ = status[3]
    damaged = cache / f"{identity}.case"
    damaged.write_bytes(damaged.read_bytes()[:-7])
    gone = cache / f"{status[5][1]}.case"
    gone.unlink()
    status = {i: why for i, _, why in crokf.training_case_status(str(scene), str(cache))}
    assert status[5] == "missing"
    assert status[index] is not None and str(damaged) in status[index]
    assert sum(why is not None for why in status.values()) == 2
    import crokf.distributed as dist

    compile_in_process = dist._crokf.compile
    seen = []

    def checked_compile(path, **kwargs):
        seen.append([why for _, _, why in crokf.training_case_status(path, kwargs["cache"])])
        return compile_in_process(path, **kwargs)

    monkeypatch.setattr(dist._crokf, "compile", checked_compile)
    model, _ = compile_distributed(scene, client=client, cache=cache, report=False, progress=False)
    assert seen == [[None] * len(status)]
    assert model.to_bytes() == reference


def test_a_changed_scene_is_built_again(scene, tmp_path):
    # The process keeps the last scene's full-order model; an edit of the scene (or its mesh)
    # is a new model, not the kept one.
    first = crokf.training_cases(str(scene))
    edited = tmp_path / "scene.toml"
    edited.write_text(
        scene.read_text().replace('file = "cantilever.msh"', f'file = "{scene.parent / "cantilever.msh"}"')
        .replace("every = 5", "every = 4")
    )
    changed = crokf.training_cases(str(edited))
    assert [c[1] for c in changed] != [c[1] for c in first]
    assert crokf.training_cases(str(scene)) == first
    edited.write_text(edited.read_text().replace("every = 4", "every = 5"))
    assert [c[1] for c in crokf.training_cases(str(edited))] != [c[1] for c in changed]


def test_cases_still_unusable_after_their_rounds_are_an_error(scene, client, tmp_path, monkeypatch):
    # Workers that write a case the client cannot use (as workers of another crokf build
    # would): the run stops naming the cases, the compile is not reached.
    import crokf.distributed as dist

    monkeypatch.setattr(dist, "_store", lambda cache, identity, data: (cache / f"{identity}.case").write_bytes(b"not a case"))
    reached = []
    monkeypatch.setattr(dist._crokf, "compile", lambda *a, **k: reached.append(1))
    with pytest.raises(crokf.CompileError, match=r"still unusable after 2 rounds.*case 0: "):
        compile_distributed(scene, client=client, cache=tmp_path / "c", report=False, progress=False)
    assert not reached
