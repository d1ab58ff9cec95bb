"""The tier's training on Dask (``crokf.distributed``): the model is byte-identical to a
compile in one process, a worker killed with a case in flight loses only that case, and a
case past its timeout is abandoned, run again, then named in the error.

Scene: the example cantilever's mesh and tier with a short training plan (the six axes,
0.2 s runs: 12 cases), so that the test runs in seconds on two local workers.
"""

import os
import re
import signal
import threading
import time

import pytest

distributed = pytest.importorskip("distributed")

import crokf  # noqa: E402
from crokf.distributed import compile_distributed, main  # noqa: E402


@pytest.fixture(scope="module")
def scene(cheap_tier_scene):
    # 0.2 s runs: these tests are about the distribution, not its accuracy.
    return cheap_tier_scene("dask", 0.2)


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


def test_a_case_timeout_is_checked():
    for bad in (0, -1, float("nan"), float("inf"), "soon"):
        with pytest.raises(ValueError, match="case timeout"):
            compile_distributed("no-such-scene.toml", case_timeout=bad)
    with pytest.raises(SystemExit):
        main(["scene.toml", "-o", "m.crokf", "--case-timeout", "0"])


def test_a_case_past_its_timeout_returns_and_its_run_is_abandoned(scene, tmp_path):
    import crokf.distributed as dist

    # A generous limit: the run in its own thread gives a usable case file (the bytes hold the
    # run's timings, so they differ from run to run).
    index, identity, _ = crokf.training_cases(str(scene))[0]
    (tmp_path / f"{identity}.case").write_bytes(dist._run_case(str(scene), index, 600.0))
    status = crokf.training_case_status(str(scene), str(tmp_path))
    assert status[0] == (index, identity, None)
    started = time.monotonic()
    late = dist._run_case(str(scene), 0, 1e-3)
    assert time.monotonic() - started < 0.05, "the task waited for the abandoned run"
    assert isinstance(late, dist._TimedOut) and late.seconds == 1e-3
    assert late.worker == "(not on a Dask worker)"
    assert dist._abandoned_running() == 1
    deadline = time.monotonic() + 60
    while dist._abandoned_running() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert dist._abandoned_running() == 0, "the abandoned run never ended"


def test_a_generous_case_timeout_keeps_the_model(scene, reference, client, tmp_path):
    model, _ = compile_distributed(
        scene, client=client, cache=tmp_path / "c", report=False, progress=False, case_timeout=600
    )
    assert model.to_bytes() == reference


def test_a_case_slow_once_is_abandoned_then_run_again(scene, reference, tmp_path, monkeypatch, capfd):
    # Workers in this process (threads), so that one case can be made slow: its first run
    # blocks until the test ends, past a 5 s limit (the others take ~0.1 s: the margin is for a
    # loaded machine); the next round runs it again.
    import crokf.distributed as dist
    from distributed import Client, LocalCluster

    slow_index = 3
    release = threading.Event()
    calls = []
    real = dist._training_case

    def training_case(path, index, worker):
        calls.append(index)
        if index == slow_index and calls.count(index) == 1:
            release.wait(120)
        return real(path, index, worker)

    monkeypatch.setattr(dist, "_training_case", training_case)
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                           dashboard_address=None)
    local = Client(cluster)
    try:
        # In-process workers have no nanny: the abandoned run is left to end, with a warning.
        with pytest.warns(RuntimeWarning, match=r"worker .* has no nanny .* 1 abandoned"):
            model, _ = compile_distributed(
                scene, client=local, cache=tmp_path / "c", report=False, case_timeout=5
            )
    finally:
        release.set()
        local.close()
        cluster.close()
    assert model.to_bytes() == reference
    assert sorted(calls) == sorted([*range(12), slow_index]), calls
    err = capfd.readouterr().err
    assert re.search(
        rf"training case {slow_index} ran past the case timeout of 5 s on worker "
        r"inproc://\S+: abandoned, counted as unusable", err
    ), err
    assert "training cases 12/12" in err


def test_cases_past_their_timeout_every_round_are_named_in_the_error(scene, client, tmp_path, monkeypatch):
    import crokf.distributed as dist

    rounds = []
    run_cases = dist._run_cases

    def counted(*args):
        out = run_cases(*args)
        rounds.append(len(out))
        return out

    monkeypatch.setattr(dist, "_run_cases", counted)
    reached = []
    monkeypatch.setattr(dist._crokf, "compile", lambda *a, **k: reached.append(1))
    cache = tmp_path / "c"
    with pytest.raises(crokf.CompileError) as caught:
        compile_distributed(
            scene, client=client, cache=cache, report=False, progress=False, case_timeout=1e-3
        )
    message = str(caught.value)
    assert message.startswith("12 training case(s) still unusable after 2 rounds"), message
    assert re.search(r"case 0: ran past the case timeout of 0\.001 s on worker tcp://\S+;", message)
    assert "and 7 more" in message and "12 ran past the case timeout: give them longer" in message
    assert "crokf build" not in message
    assert rounds == [12, 12] and not reached
    assert not list(cache.glob("*.case"))
    # The workers left computing abandoned cases were restarted (LocalCluster: nannies).
    client.wait_for_workers(2, timeout=60)
    assert set(client.run(dist._abandoned_running).values()) == {0}
