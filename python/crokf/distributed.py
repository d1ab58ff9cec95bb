"""The co-rotational tier's training on Dask, then the compile.

    python -m crokf.distributed SCENE -o MODEL [--workers N | --scheduler ADDRESS |
                                                --jobqueue slurm|pbs --cores C --memory M ...]
                                               [--cache DIR] [--case-timeout SECONDS]

The training runs of a scene's ``[reduction.corotational]`` tier are independent cases
(``crokf-compile SCENE --list-cases``). Each case the cache does not hold usable runs as one
Dask task (``run_training_case``, in the worker's process, the GIL released; each worker
process builds the scene's full-order model once and reuses it for all its cases); the client
writes each result into the case cache as it arrives and releases it, then checks every case
file (identity, checksum, sizes: ``training_case_status``), runs any that is not usable again on
the cluster, and compiles with that cache. The model is byte-identical to
``crokf-compile SCENE -o MODEL``.

A worker that dies mid-case loses only that case: the scheduler runs it again on another
worker (its ``allowed-failures``), and the cases already gathered stay in the cache. An interrupted run
resumes from the cache: run the same command again. A case that fails on a worker (a scene or
mesh the worker cannot read) stops the run with the worker's address and its message.

``--case-timeout SECONDS`` bounds each case's run on its worker (the clock starts when the
worker starts the case, not while it waits in the queue). A case still running then is
abandoned: its task returns, nothing is stored, it counts as unusable and runs again in the
next round; still over the limit after the rounds, the run stops naming the case, its worker
and the timeout. The training code cannot be interrupted inside a process, so a worker left
computing an abandoned case is restarted by its nanny once the round's other cases are in (a
worker without a nanny is left to finish it, with a warning).

Without ``--scheduler``, a ``LocalCluster`` of ``--workers`` processes (one thread each) runs
on this machine. With ``--scheduler ADDRESS`` any ``dask.distributed`` scheduler is used
(Kubernetes, workers started by hand); with ``--jobqueue slurm|pbs`` this process starts a
scheduler and submits ``--jobs`` batch jobs of ``--cores`` worker processes each through
dask-jobqueue (``jobqueue_cluster``; ``--print-job-script`` shows the job script and submits
nothing). The workers need the ``crokf`` package and must see the scene and its mesh at the
same absolute paths (a shared file system). The cache folder is only written by this process.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path
from typing import NamedTuple

from . import _crokf

__all__ = ["compile_distributed", "jobqueue_cluster", "main"]

#: Rounds of "check the case files, run the unusable ones again" before the compile.
CHECK_ROUNDS = 2


def _store(cache: Path, identity: str, data: bytes) -> None:
    """Writes a case file in one step: a temporary sibling, then a rename."""
    target = cache / f"{identity}.case"
    fd, tmp = tempfile.mkstemp(prefix=f".{identity}.", suffix=".tmp", dir=cache)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, target)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


class _Progress:
    """`training cases: done/total` with the time left, on one line of stderr."""

    def __init__(self, total: int, done: int, stream=None):
        self.total, self.done, self.start_done = total, done, done
        self.started = time.monotonic()
        # This call's stderr, not the one at import (a redirection since is followed).
        self.stream = sys.stderr if stream is None else stream
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()

    def rerun(self, done: int) -> None:
        """A new round: ``done`` cases are usable (cases found unusable after their run are to
        run again)."""
        self.start_done -= self.done - done
        self.done = done

    def note(self, message: str) -> None:
        """A line of its own (the progress line goes on below it)."""
        self.stream.write(("\r\033[K" if self.tty else "") + f"crokf.distributed: {message}\n")
        self.stream.flush()

    def update(self, done: int) -> None:
        self.done = done
        ran = done - self.start_done
        elapsed = time.monotonic() - self.started
        left = ""
        if 0 < ran and done < self.total:
            left = f", about {elapsed / ran * (self.total - done):.0f} s left"
        elif done == self.total:
            left = f", {ran} run in {elapsed:.1f} s"
        line = f"crokf.distributed: training cases {done}/{self.total}{left}"
        if self.tty:
            self.stream.write("\r" + line + "\033[K")
            if done == self.total:
                self.stream.write("\n")
        else:
            self.stream.write(line + "\n")
        self.stream.flush()


def compile_distributed(
    scene,
    output=None,
    *,
    client=None,
    workers: int = 2,
    scheduler: str | None = None,
    cache=None,
    report: bool = True,
    progress=True,
    case_timeout: float | None = None,
):
    """Runs ``scene``'s training cases on Dask, then compiles; returns ``(model, report)``.

    ``client``: a ``distributed.Client`` to use (else one to ``scheduler``, else a
    ``LocalCluster`` of ``workers`` processes). ``cache``: the case cache folder (created when
    missing, kept); without it, ``OUTPUT.cases`` beside ``output`` (removed after a
    successful compile, kept after a failure so that the next run resumes), or a temporary
    folder when there is no ``output``. ``output``: write the model file there.
    ``report=False`` skips the measured error (as ``crokf.compile``). ``case_timeout``:
    seconds a case may run on its worker before it is abandoned and counts as unusable (run
    again in the next round, then named in the error); ``None``: no limit.
    """
    case_timeout = _check_timeout(case_timeout)
    scene = Path(scene).resolve()
    if not scene.is_file():
        raise _crokf.CompileError(f"{scene}: no such scene file")
    cases = _crokf.training_cases(str(scene))
    owned_temporary = None
    remove_after = False
    if cache is None:
        if output is not None:
            # Kept after a failure (the next run resumes from it), removed after a success.
            cache = Path(str(output) + ".cases")
            remove_after = True
        else:
            owned_temporary = tempfile.TemporaryDirectory(prefix="crokf-cases-")
            cache = owned_temporary.name
    cache = Path(cache)
    if cache.exists() and not cache.is_dir():
        raise _crokf.CompileError(f"training cache {cache}: is a file, not a folder")
    cache.mkdir(parents=True, exist_ok=True)
    cluster = _Cluster(client, workers, scheduler)
    try:
        line = None
        # identity -> why, for the cases that ran past the timeout in the last round they ran.
        timed_out: dict[str, str] = {}
        for _ in range(CHECK_ROUNDS):
            status = _crokf.training_case_status(str(scene), str(cache))
            missing = [(index, identity) for index, identity, why in status if why is not None]
            if not missing:
                break
            if progress:
                if line is None:
                    line = _Progress(len(cases), len(cases) - len(missing))
                else:
                    line.rerun(len(cases) - len(missing))
            for _, identity in missing:
                timed_out.pop(identity, None)
            timed_out.update(
                _run_cases(scene, missing, cache, cluster.client(), line, case_timeout)
            )
        else:
            # Still unusable after its re-runs (workers of another crokf build, a cache they
            # cannot write the same, a case past the timeout): say so instead of the compile
            # computing them here.
            status = _crokf.training_case_status(str(scene), str(cache))
            bad = [(index, timed_out.get(identity, why)) for index, identity, why in status
                   if why is not None]
            if bad:
                listed = "; ".join(f"case {index}: {why}" for index, why in bad[:5])
                more = f" and {len(bad) - 5} more" if len(bad) > 5 else ""
                slow = sum(identity in timed_out for _, identity, why in status if why is not None)
                hints = []
                if slow:
                    hints.append(f"{slow} ran past the case timeout: give them longer")
                if slow < len(bad):
                    hints.append("do the workers run this crokf build?")
                raise _crokf.CompileError(
                    f"{len(bad)} training case(s) still unusable after {CHECK_ROUNDS} rounds on "
                    f"the cluster ({listed}{more}): {'; '.join(hints)}"
                )
        cluster.close()
        # The listing and the checks kept the scene's full-order model here; the compile builds
        # its own.
        _crokf.forget_full_order()
        model, rep = _crokf.compile(str(scene), report=report, cache=str(cache))
        if output is not None:
            model.save(str(output))
        if remove_after:
            for c in cases:
                (cache / f"{c[1]}.case").unlink(missing_ok=True)
            try:
                cache.rmdir()
            except OSError:
                pass  # something else lives there: leave the folder
        return model, rep
    finally:
        cluster.close()
        _crokf.forget_full_order()
        if owned_temporary is not None:
            owned_temporary.cleanup()


def _check_timeout(seconds):
    if seconds is None:
        return None
    try:
        value = float(seconds)
    except (TypeError, ValueError):
        raise ValueError(f"case timeout {seconds!r}: not a number of seconds") from None
    if not (value > 0 and math.isfinite(value)):
        raise ValueError(f"case timeout {seconds!r}: must be a positive number of seconds")
    return value


class _TimedOut(NamedTuple):
    """What a case's task returns when the case ran past its timeout on the worker."""

    worker: str
    seconds: float


#: This process's abandoned case runs (threads still inside the training code).
_ABANDONED: list[threading.Thread] = []


def _abandoned_running() -> int:
    """On a worker: how many abandoned case runs of this process are still computing."""
    _ABANDONED[:] = [t for t in _ABANDONED if t.is_alive()]
    return len(_ABANDONED)


def _worker_address() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return "(not on a Dask worker)"


def _training_case(scene: str, index: int, worker: str) -> bytes:
    try:
        return _crokf.run_training_case(scene, index)
    except _crokf.CrokfError as e:
        raise _crokf.CompileError(f"training case {index} on worker {worker}: {e}") from None


def _run_case(scene: str, index: int, timeout: float | None = None):
    """One case on a worker: its case file's bytes, or ``_TimedOut`` when it ran past
    ``timeout`` seconds (the run then goes on in an abandoned thread, its result dropped); a
    failure names the worker."""
    worker = _worker_address()
    if timeout is None:
        return _training_case(scene, index, worker)
    outcome = {}

    def run():
        try:
            outcome["data"] = _training_case(scene, index, worker)
        except BaseException as e:  # noqa: BLE001 - raised again in the task's thread below
            outcome["error"] = e

    thread = threading.Thread(target=run, name=f"crokf-case-{index}", daemon=True)
    thread.start()
    thread.join(timeout)
    if thread.is_alive():
        _ABANDONED.append(thread)
        return _TimedOut(worker, timeout)
    if "error" in outcome:
        raise outcome["error"]
    return outcome["data"]


class _Cluster:
    """The client the cases run on: the caller's, or one made at first use (to ``scheduler``,
    else a ``LocalCluster`` of ``workers`` processes) and closed by ``close``."""

    def __init__(self, client, workers, scheduler):
        self._client, self._workers, self._scheduler = client, workers, scheduler
        self._own = []

    def client(self):
        if self._client is None:
            from distributed import Client, LocalCluster

            if self._scheduler is not None:
                self._client = Client(self._scheduler)
                self._own.append(self._client)
            else:
                cluster = LocalCluster(
                    n_workers=self._workers, threads_per_worker=1, processes=True,
                    dashboard_address=None,
                )
                self._own.append(cluster)
                self._client = Client(cluster)
                self._own.insert(0, self._client)
        return self._client

    def close(self):
        while self._own:
            self._own.pop(0).close()


def _seconds(value: float) -> str:
    return f"{value:g} s"


def _run_cases(scene, missing, cache, client, line, timeout):
    """Runs ``missing`` cases, storing each as it arrives; returns ``{identity: why}`` for the
    cases that ran past ``timeout``."""
    from distributed import as_completed

    futures = {
        client.submit(
            _run_case, str(scene), index, timeout, key=f"crokf-case-{identity}", pure=False,
        ): (index, identity)
        for index, identity in missing
    }
    done = line.done if line else 0
    timed_out = {}
    abandoned = set()
    try:
        for future in as_completed(list(futures)):
            index, identity = futures.pop(future)
            result = future.result()
            # Stored (or dropped): the scheduler and the worker may forget it now, not at the end.
            future.release()
            if isinstance(result, _TimedOut):
                why = (f"ran past the case timeout of {_seconds(result.seconds)} on worker "
                       f"{result.worker}")
                timed_out[identity] = why
                abandoned.add(result.worker)
                if line:
                    line.note(f"training case {index} {why}: abandoned, counted as unusable")
                continue
            _store(cache, identity, result)
            del result
            done += 1
            if line:
                line.update(done)
    finally:
        if abandoned:
            _restart_abandoned(client, sorted(abandoned))
    return timed_out


def _restart_abandoned(client, workers):
    """Restarts (through their nannies) the workers still computing an abandoned case, once the
    round's cases are in; a worker without a nanny is left to finish, with a warning. Called
    while cleaning up: a failure here is a warning, not a replacement of the run's outcome."""
    try:
        running = client.run(_abandoned_running, workers=workers, on_error="return")
        busy = [w for w in workers if isinstance(running.get(w), int) and running[w] > 0]
        if not busy:
            return
        info = client.scheduler_info(n_workers=-1)["workers"]
        nanny = [w for w in busy if info.get(w, {}).get("nanny")]
        for w in busy:
            if w not in nanny:
                warnings.warn(
                    f"crokf.distributed: worker {w} has no nanny to restart it: it goes on "
                    f"computing {running[w]} abandoned training case(s) until they end",
                    RuntimeWarning, stacklevel=1,
                )
        if nanny:
            result = client.restart_workers(nanny, raise_for_error=False)
            for w, state in result.items():
                if state != "OK":
                    warnings.warn(
                        f"crokf.distributed: worker {w}, restarted to stop an abandoned "
                        f"training case: {state}", RuntimeWarning, stacklevel=1,
                    )
    except Exception as e:  # noqa: BLE001 - reported, and the run's own outcome stands
        warnings.warn(
            f"crokf.distributed: could not restart the workers {', '.join(workers)} computing "
            f"abandoned training cases: {type(e).__name__}: {e}", RuntimeWarning, stacklevel=1,
        )


#: ``--jobqueue`` kinds and their dask-jobqueue classes.
JOBQUEUES = {"slurm": "SLURMCluster", "pbs": "PBSCluster"}


def jobqueue_cluster(
    kind: str,
    *,
    cores: int,
    memory: str,
    walltime: str | None = None,
    queue: str | None = None,
    account: str | None = None,
    processes: int | None = None,
    job_extra_directives=(),
    job_script_prologue=(),
    interface: str | None = None,
    **kwargs,
):
    """A dask-jobqueue cluster (``kind``: ``"slurm"`` or ``"pbs"``) for the training cases.

    Each batch job asks for ``cores`` cores and ``memory`` (dask-jobqueue's units, ``"16GB"``)
    and runs ``processes`` worker processes of one thread each (default ``cores``: a case is
    one process's work, and each process keeps its own copy of the scene's full-order model,
    so ``memory`` is shared among them). ``walltime``, ``queue``, ``account``: the job's, else
    dask-jobqueue's configuration; ``job_extra_directives``: more ``#SBATCH`` / ``#PBS``
    lines; ``job_script_prologue``: shell lines before the worker starts (``module load``,
    ``source venv/bin/activate``); ``interface``: the network interface of the scheduler and the
    workers (``"ib0"``). Other keywords go to the dask-jobqueue class. Nothing is submitted
    until ``cluster.scale(jobs=N)``; ``cluster.job_script()`` shows what would be.
    """
    if kind not in JOBQUEUES:
        raise ValueError(f"jobqueue {kind!r}: not one of {', '.join(JOBQUEUES)}")
    processes = cores if processes is None else processes
    if not (isinstance(cores, int) and cores >= 1):
        raise ValueError(f"cores {cores!r}: must be a whole number, at least 1")
    if not (isinstance(processes, int) and 1 <= processes <= cores and cores % processes == 0):
        raise ValueError(
            f"processes {processes!r}: must divide cores ({cores}) to give each worker process "
            "the same number of threads"
        )
    try:
        import dask_jobqueue
    except ImportError as e:
        raise ImportError(
            f"the {kind} cluster needs dask-jobqueue (pip install dask-jobqueue): {e}"
        ) from e
    options = {"walltime": walltime, "queue": queue, "account": account, "interface": interface}
    kwargs.update({k: v for k, v in options.items() if v is not None})
    return getattr(dask_jobqueue, JOBQUEUES[kind])(
        cores=cores, processes=processes, memory=memory,
        job_extra_directives=list(job_extra_directives),
        job_script_prologue=list(job_script_prologue), **kwargs,
    )


def _positive_seconds(text: str) -> float:
    try:
        return _check_timeout(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m crokf.distributed",
        description="Run a scene's co-rotational training cases on Dask, then compile "
        "(the model is byte-identical to crokf-compile SCENE -o MODEL).",
    )
    parser.add_argument("scene", help="scene file (TOML) with [reduction.corotational]")
    parser.add_argument("-o", "--output", required=True, help="model file to write")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=2,
                       help="local worker processes (default 2)")
    where.add_argument("--scheduler", help="address of a running dask.distributed scheduler")
    where.add_argument("--jobqueue", choices=sorted(JOBQUEUES),
                       help="start the workers as batch jobs through dask-jobqueue")
    parser.add_argument("--cache", help="case cache folder (default: OUTPUT.cases, removed "
                        "after a successful compile)")
    parser.add_argument("--case-timeout", type=_positive_seconds, metavar="SECONDS",
                        help="abandon a case still running on its worker after SECONDS: it "
                        "counts as unusable and runs again in the next round")
    parser.add_argument("--no-measure", action="store_true",
                        help="skip the measured error (as crokf-compile --no-measure)")
    jobs = parser.add_argument_group("batch jobs (with --jobqueue)")
    jobs.add_argument("--cores", type=int, help="cores per job (required)")
    jobs.add_argument("--memory", help='memory per job, e.g. "16GB" (required)')
    jobs.add_argument("--processes", type=int,
                      help="worker processes per job, one thread each (default: --cores)")
    jobs.add_argument("--jobs", type=int, help="jobs to submit (default 1)")
    jobs.add_argument("--walltime", help='e.g. "02:00:00"')
    jobs.add_argument("--queue", help="partition (Slurm) or queue (PBS)")
    jobs.add_argument("--account", help="account or project to charge")
    jobs.add_argument("--interface", help='network interface of scheduler and workers, e.g. "ib0"')
    jobs.add_argument("--job-extra", action="append", default=[], metavar="DIRECTIVE",
                      help="another #SBATCH / #PBS directive, e.g. --job-extra=--exclusive (repeatable)")
    jobs.add_argument("--job-prologue", action="append", default=[], metavar="LINE",
                      help="a shell line run before the worker starts (repeatable)")
    jobs.add_argument("--print-job-script", action="store_true",
                      help="print the job script and stop (submits nothing, compiles nothing)")
    args = parser.parse_args(argv)
    if args.workers < 1:
        parser.error("--workers must be at least 1")
    job_options = ["cores", "memory", "processes", "jobs", "walltime", "queue", "account",
                   "interface", "job_extra", "job_prologue", "print_job_script"]
    if args.jobqueue is None:
        given = [o for o in job_options if getattr(args, o) not in (None, [], False)]
        if given:
            parser.error(f"--{given[0].replace('_', '-')} needs --jobqueue")
    else:
        for o in ("cores", "memory"):
            if getattr(args, o) is None:
                parser.error(f"--jobqueue {args.jobqueue} needs --{o}")
        if args.jobs is not None and args.jobs < 1:
            parser.error("--jobs must be at least 1")
    batch = client = None
    if args.jobqueue is not None:
        try:
            batch = jobqueue_cluster(
                args.jobqueue, cores=args.cores, memory=args.memory, walltime=args.walltime,
                queue=args.queue, account=args.account, processes=args.processes,
                job_extra_directives=args.job_extra, job_script_prologue=args.job_prologue,
                interface=args.interface,
            )
        except (ImportError, ValueError) as e:
            print(f"crokf.distributed: error: {e}", file=sys.stderr)
            return 2
    try:
        if batch is not None:
            if args.print_job_script:
                print(batch.job_script())
                return 0
            from distributed import Client

            batch.scale(jobs=args.jobs or 1)
            client = Client(batch)
        compile_distributed(
            args.scene, args.output, client=client,
            workers=args.workers, scheduler=args.scheduler,
            cache=args.cache, report=not args.no_measure, case_timeout=args.case_timeout,
        )
    except _crokf.CrokfError as e:
        print(f"crokf.distributed: error: {e}", file=sys.stderr)
        return 1
    finally:
        if client is not None:
            client.close()
        if batch is not None:
            batch.close()
    print(f"wrote {args.output}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
