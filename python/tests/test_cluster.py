"""``crokf.distributed`` run the way a cluster operator runs it: a ``dask scheduler`` and two
``dask worker`` processes started apart on loopback, ``python -m crokf.distributed --scheduler
ADDRESS``, one worker killed (SIGKILL, its whole process group) with cases in flight; and the
dask-jobqueue job scripts (built, never submitted: no queue is needed).

Scene: the example cantilever's mesh and tier, the six axes with 1 s runs (12 cases of ~0.4 s,
long enough for the kill to land mid-run).
"""

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

distributed = pytest.importorskip("distributed")

import crokf  # noqa: E402
from crokf.distributed import main  # noqa: E402


@pytest.fixture(scope="module")
def scene(cheap_tier_scene):
    # 1 s runs (~0.4 s a case): long enough for the kill to land mid-run.
    return cheap_tier_scene("cluster", 1.0)


def _dask_commands():
    """``(scheduler, worker)`` command lines: the ``dask`` CLI of this interpreter's
    environment, else the one on PATH, else the older ``dask-scheduler`` / ``dask-worker``."""
    here = Path(sys.executable).parent
    for dask in (here / "dask", shutil.which("dask")):
        if dask and Path(dask).is_file():
            return [str(dask), "scheduler"], [str(dask), "worker"]
    old = [here / "dask-scheduler", here / "dask-worker"]
    if not all(p.is_file() for p in old):
        old = [shutil.which("dask-scheduler"), shutil.which("dask-worker")]
    if all(old):
        return [str(old[0])], [str(old[1])]
    pytest.skip("the dask command line (dask scheduler / dask worker) is not installed: "
                'pip install "dask[distributed]"')


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _Processes:
    """Subprocesses, each in its own session (process group), with their output in ``logs``;
    ``kill`` ends a whole group, ``close`` ends every one still running."""

    def __init__(self, logs: Path):
        self.logs, self.procs = logs, {}
        logs.mkdir()

    def start(self, name, cmd, **kwargs):
        with open(self.logs / f"{name}.log", "wb") as out:
            self.procs[name] = subprocess.Popen(
                cmd, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                start_new_session=True, **kwargs,
            )
        return self.procs[name]

    def kill(self, name):
        proc = self.procs[name]
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass  # already gone
        proc.wait(timeout=30)

    def close(self):
        for name in list(self.procs):
            self.kill(name)

    def tails(self, lines=15):
        out = []
        for log in sorted(self.logs.glob("*.log")):
            text = log.read_text(errors="replace").splitlines()[-lines:]
            out.append(f"--- {log.name} ---\n" + "\n".join(text))
        return "\n".join(out)


def _wait(what, condition, seconds, procs):
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if condition():
            return
        for name, p in procs.procs.items():
            if p.poll() is not None:
                pytest.fail(f"{name} exited ({p.returncode}) while waiting for {what}\n"
                            + procs.tails())
        time.sleep(0.05)
    pytest.fail(f"timed out after {seconds} s waiting for {what}\n" + procs.tails())


def _listening(port):
    try:
        socket.create_connection(("127.0.0.1", port), timeout=1).close()
        return True
    except OSError:
        return False


def test_a_killed_worker_under_a_separate_scheduler_keeps_the_model(scene, tmp_path):
    scheduler_cmd, worker_cmd = _dask_commands()
    cases = crokf.training_cases(str(scene))
    assert len(cases) == 12
    started = time.monotonic()
    reference = crokf.compile(str(scene), report=False)[0].to_bytes()
    in_one_process = time.monotonic() - started

    procs = _Processes(tmp_path / "logs")
    monitor = None
    try:
        port = _free_port()
        address = f"tcp://127.0.0.1:{port}"
        procs.start("scheduler", [*scheduler_cmd, "--host", "127.0.0.1", "--port", str(port),
                                  "--no-dashboard"], cwd=tmp_path)
        _wait(f"the scheduler to listen on {address}", lambda: _listening(port), 60, procs)
        for k in range(2):
            procs.start(f"worker{k}", [*worker_cmd, address, "--nworkers", "1", "--nthreads", "1",
                                       "--no-dashboard", "--name", f"w{k}",
                                       "--local-directory", str(tmp_path / f"w{k}")],
                        cwd=tmp_path)
        monitor = distributed.Client(address, timeout=30)
        monitor.wait_for_workers(2, timeout=60)
        # Each worker process is the child of its `dask worker` command (the nanny).
        nanny_pid = monitor.run(os.getppid)
        owner = {p.pid: name for name, p in procs.procs.items()}
        assert sorted(owner.get(pid, pid) for pid in nanny_pid.values()) == ["worker0", "worker1"]
        assert set(monitor.run(lambda: crokf.__file__).values()) == {crokf.__file__}, \
            "the workers import another crokf"

        cache, out = tmp_path / "cases", tmp_path / "model.crokf"
        started = time.monotonic()
        compile_ = procs.start(
            "compile",
            [sys.executable, "-m", "crokf.distributed", str(scene), "-o", str(out),
             "--scheduler", address, "--cache", str(cache), "--no-measure"],
            cwd=tmp_path,
        )
        killed = None
        deadline = started + 180
        while compile_.poll() is None and time.monotonic() < deadline:
            if killed is None:
                stored = ({p.name: p.stat().st_mtime_ns for p in cache.glob("*.case")}
                          if cache.is_dir() else {})
                if 0 < len(stored) < len(cases):
                    busy = {w: keys for w, keys in monitor.processing().items() if keys}
                    if busy:
                        worker = min(busy)
                        name = owner[nanny_pid[worker]]
                        procs.kill(name)
                        killed = {"worker": worker, "name": name, "keys": list(busy[worker]),
                                  "stored": stored, "at": time.monotonic() - started}
            time.sleep(0.01)
        if compile_.poll() is None:
            pytest.fail("the compile through the scheduler did not end in 180 s\n" + procs.tails())
        elapsed = time.monotonic() - started
        log = (procs.logs / "compile.log").read_text(errors="replace")
        assert compile_.returncode == 0, procs.tails(40)
        assert killed is not None, "no worker was caught with a case in flight\n" + log
        assert procs.procs[killed["name"]].returncode == -signal.SIGKILL
        assert f"wrote {out}" in log

        assert out.read_bytes() == reference
        files = sorted(p.name for p in cache.glob("*.case"))
        assert files == sorted(f"{c[1]}.case" for c in cases)
        assert not list(cache.glob(".*.tmp")), "no temporary left"
        # The cases stored before the kill were not run again; the killed worker's were, on the
        # other worker (the only one the scheduler has left).
        for name, mtime in killed["stored"].items():
            assert (cache / name).stat().st_mtime_ns == mtime, name
        in_flight = [k.removeprefix("crokf-case-") for k in killed["keys"]]
        assert all(k.startswith("crokf-case-") for k in killed["keys"]), killed["keys"]
        assert all(f"{i}.case" in files and f"{i}.case" not in killed["stored"] for i in in_flight)
        assert list(monitor.scheduler_info()["workers"]) != [killed["worker"]]
        assert len(monitor.scheduler_info()["workers"]) == 1
        print(
            f"\nin one process {in_one_process:.1f} s; through {address} with {killed['name']} "
            f"killed at {killed['at']:.1f} s ({len(killed['stored'])} of {len(cases)} cases "
            f"stored, {len(in_flight)} in flight on it, running or queued, then run on the "
            f"other): {elapsed:.1f} s"
        )
    finally:
        if monitor is not None:
            monitor.close()
        procs.close()


@pytest.fixture()
def jobqueue():
    return pytest.importorskip(
        "dask_jobqueue", reason="dask-jobqueue is not installed (pip install dask-jobqueue)"
    )


def _worker_line(script):
    lines = [line for line in script.splitlines() if "distributed.cli.dask_worker" in line]
    assert len(lines) == 1, script
    return lines[0]


@pytest.mark.parametrize("kind", ["slurm", "pbs"])
def test_a_jobqueue_cluster_job_script(jobqueue, kind):
    from crokf.distributed import jobqueue_cluster

    cluster = jobqueue_cluster(
        kind, cores=4, memory="16GB", walltime="02:00:00", queue="batch", account="proj42",
        job_script_prologue=["source /opt/crokf/venv/bin/activate"],
        scheduler_options={"dashboard_address": None},
    )
    try:
        script, scheduler = cluster.job_script(), cluster.scheduler_address
    finally:
        cluster.close()
    lines = script.splitlines()
    # 16 GB = 14.9 GiB: dask-jobqueue asks for whole GiB; each of the 4 worker processes gets
    # a quarter as its memory limit.
    if kind == "slurm":
        for want in ("#SBATCH -p batch", "#SBATCH -A proj42", "#SBATCH -n 1",
                     "#SBATCH --cpus-per-task=4", "#SBATCH --mem=15G", "#SBATCH -t 02:00:00"):
            assert want in lines, (want, script)
    else:
        for want in ("#PBS -q batch", "#PBS -A proj42", "#PBS -l select=1:ncpus=4:mem=15GB",
                     "#PBS -l walltime=02:00:00"):
            assert want in lines, (want, script)
    worker = _worker_line(script)
    assert worker.startswith(f"{sys.executable} -m distributed.cli.dask_worker {scheduler} "), worker
    # One thread per worker process, one process per core: a case is one process's work.
    assert re.search(r" --nthreads 1 ", worker) and re.search(r" --nworkers 4 ", worker), worker
    assert " --memory-limit 3.73GiB " in worker and " --nanny " in worker, worker
    assert lines.index("source /opt/crokf/venv/bin/activate") < lines.index(worker)


def test_the_command_line_prints_a_job_script_and_submits_nothing(jobqueue, scene, tmp_path, capsys):
    out = tmp_path / "m.crokf"
    code = main([str(scene), "-o", str(out), "--jobqueue", "slurm", "--cores", "2",
                 "--processes", "1", "--memory", "8GB", "--walltime", "00:30:00",
                 "--job-extra=--exclusive", "--print-job-script"])
    assert code == 0
    script = capsys.readouterr().out
    assert "#SBATCH --exclusive" in script.splitlines() and "#SBATCH -t 00:30:00" in script
    worker = _worker_line(script)
    assert " --nthreads 2 " in worker and " --nworkers " not in worker, worker
    assert not out.exists() and not (tmp_path / "m.crokf.cases").exists()


def test_the_command_line_checks_its_jobqueue_options(scene, tmp_path, capsys):
    out = str(tmp_path / "m.crokf")
    for argv, said in [
        (["--cores", "4"], "--cores needs --jobqueue"),
        (["--jobqueue", "pbs", "--memory", "4GB"], "--jobqueue pbs needs --cores"),
        (["--jobqueue", "slurm", "--cores", "4"], "--jobqueue slurm needs --memory"),
        (["--jobqueue", "slurm", "--scheduler", "tcp://127.0.0.1:1"], "not allowed with"),
    ]:
        with pytest.raises(SystemExit) as e:
            main([str(scene), "-o", out, *argv])
        assert e.value.code == 2
        assert said in capsys.readouterr().err, argv
    code = main([str(scene), "-o", out, "--jobqueue", "slurm", "--cores", "4", "--processes",
                 "3", "--memory", "4GB"])
    assert code == 2
    assert "processes 3: must divide cores (4)" in capsys.readouterr().err
