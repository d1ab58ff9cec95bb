"""The co-rotational tier's training on Dask, then the compile.

    python -m crokf.distributed SCENE -o MODEL [--workers N | --scheduler ADDRESS] [--cache DIR]

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

Without ``--scheduler``, a ``LocalCluster`` of ``--workers`` processes (one thread each) runs
on this machine. With ``--scheduler ADDRESS`` any ``dask.distributed`` scheduler is used
(dask-jobqueue's Slurm or PBS clusters, Kubernetes); its workers need the ``crokf`` package
and must see the scene and its mesh at the same absolute paths (a shared file system). The
cache folder is only written by this process.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from . import _crokf

__all__ = ["compile_distributed", "main"]

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

    def __init__(self, total: int, done: int, stream=sys.stderr):
        self.total, self.done, self.start_done = total, done, done
        self.started = time.monotonic()
        self.stream = stream
        self.tty = hasattr(stream, "isatty") and stream.isatty()

    def rerun(self, count: int) -> None:
        """``count`` cases found unusable after their run are to run again."""
        self.done -= count
        self.start_done -= count

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
):
    """Runs ``scene``'s training cases on Dask, then compiles; returns ``(model, report)``.

    ``client``: a ``distributed.Client`` to use (else one to ``scheduler``, else a
    ``LocalCluster`` of ``workers`` processes). ``cache``: the case cache folder (created when
    missing, kept); without it, ``OUTPUT.cases`` beside ``output`` (removed after a
    successful compile, kept after a failure so that the next run resumes), or a temporary
    folder when there is no ``output``. ``output``: write the model file there.
    ``report=False`` skips the measured error (as ``crokf.compile``).
    """
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
        for _ in range(CHECK_ROUNDS):
            status = _crokf.training_case_status(str(scene), str(cache))
            missing = [(index, identity) for index, identity, why in status if why is not None]
            if not missing:
                break
            if line is None and progress:
                line = _Progress(len(cases), len(cases) - len(missing))
            elif line is not None:
                line.rerun(len(missing))
            _run_cases(scene, missing, cache, cluster.client(), line)
        else:
            # Still unusable after its re-runs (workers of another crokf build, a cache they
            # cannot write the same): say so instead of the compile computing them here.
            status = _crokf.training_case_status(str(scene), str(cache))
            bad = [(index, why) for index, _, why in status if why is not None]
            if bad:
                listed = "; ".join(f"case {index}: {why}" for index, why in bad[:5])
                more = f" and {len(bad) - 5} more" if len(bad) > 5 else ""
                raise _crokf.CompileError(
                    f"{len(bad)} training case(s) still unusable after {CHECK_ROUNDS} rounds on "
                    f"the cluster ({listed}{more}): do the workers run this crokf build?"
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


def _run_case(scene: str, index: int) -> bytes:
    """One case on a worker; a failure names the worker."""
    try:
        return _crokf.run_training_case(scene, index)
    except _crokf.CrokfError as e:
        try:
            from distributed import get_worker

            where = f"worker {get_worker().address}"
        except (ImportError, ValueError):
            where = "a worker"
        raise _crokf.CompileError(f"training case {index} on {where}: {e}") from None


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


def _run_cases(scene, missing, cache, client, line):
    from distributed import as_completed

    futures = {
        client.submit(
            _run_case, str(scene), index, key=f"crokf-case-{identity}", pure=False,
        ): identity
        for index, identity in missing
    }
    done = line.done if line else 0
    for future in as_completed(list(futures)):
        identity = futures.pop(future)
        data = future.result()
        _store(cache, identity, data)
        # Stored: the scheduler and the worker may drop the result now, not at the end.
        future.release()
        del data
        done += 1
        if line:
            line.update(done)


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
    parser.add_argument("--cache", help="case cache folder (default: OUTPUT.cases, removed "
                        "after a successful compile)")
    parser.add_argument("--no-measure", action="store_true",
                        help="skip the measured error (as crokf-compile --no-measure)")
    args = parser.parse_args(argv)
    if args.workers < 1:
        parser.error("--workers must be at least 1")
    try:
        compile_distributed(
            args.scene, args.output, workers=args.workers, scheduler=args.scheduler,
            cache=args.cache, report=not args.no_measure,
        )
    except _crokf.CrokfError as e:
        print(f"crokf.distributed: error: {e}", file=sys.stderr)
        return 1
    print(f"wrote {args.output}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
