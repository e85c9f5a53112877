"""Engines: run fleet jobs locally, in a process pool or on Ray, through one interface.

``run_engine(engine, jobs, on_start, on_outcome, ...)`` runs every ``Job`` (sent as its plain
``to_dict``; ``jobs.run_job`` runs it in the worker) and calls ``on_start([ids])`` when jobs are
handed to workers and ``on_outcome(outcome)`` (``jobs.run_job``'s dict) as each one ends, in the
driver process. A job's own failure (``HybridCalibError``: corrupt data, ...) is an outcome, never
retried here; a system failure (a worker killed, an ``OSError``) is retried up to ``retries`` times,
then recorded as ``failed`` with its reason. At most ``in_flight`` jobs (default 2 x workers; on a
joined Ray cluster at least 2 x its CPUs / threads) are handed out at once, so a fleet of thousands
never queues thousands of tasks, and a worker that finishes finds its next job already queued.

- ``local``: in this process, one after another (debugging; same code path in the job).
- ``process``: ``concurrent.futures.ProcessPoolExecutor`` with the spawn context (no forked GTSAM /
  torch state), torch / BLAS threads set in each worker; a pool broken by a killed worker is rebuilt
  and every job that was on it is handed out again (its ``attempts`` counts each hand-out).
- ``ray``: ``ray.init(address=...)`` joins a running cluster (every node needs this package
  installed, and the roots and ``OUT`` at the same paths, i.e. a shared file system: a job reads its
  root and writes ``OUT/vehicles/<id>``, the driver reads the result files); without an address a
  local cluster of ``workers`` CPUs starts with its object store capped (``object_store_mb``), its
  temp files under ``temp_dir`` (``RAY_TMPDIR`` too) and its workers at the driver's niceness
  (``LOCAL_RAY_CONFIG``; Ray's default renices them by +15). Tasks are
  ``_remote_job`` (``run_job`` after ``_init_worker``) with ``num_cpus`` = the job's threads,
  ``max_retries=retries`` (Ray reruns a task whose worker or node died) and
  ``retry_exceptions=[OSError]`` (transient I/O); a ``DataError`` is an outcome, never an exception,
  so it is not retried. Ray reuses its worker processes, so a worker imports the calibration stack
  once, at its first job. No ``runtime_env``: one would make Ray start fresh workers for the job
  instead of the ones it prestarted (the first jobs started 3-5 s later: ``benchmarks/bench_ray_start.py``).

Workers get their thread variables (``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``, ...) and
``TQDM_DISABLE`` from the environment they are started with (``_worker_env``, also around a local
``ray.init`` in ``start_ray``, so the tests and benchmarks that call it get the engine's workers):
numpy's OpenBLAS reads them at import, before any initializer could set them (it started a second
thread per worker before).
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from hybrid_calib.errors import OptionError
from hybrid_calib.fleet.jobs import Job, run_job, set_threads

ENGINES = ("local", "process", "ray")
# A local Ray's settings (not applied to a joined cluster: its own). ``worker_niceness`` 0: Ray renices
# its workers by +15 by default (to keep its daemons responsive on a node it shares with a user's other
# work); here the workers ARE the work, as in the process pool, whose workers keep the driver's
# niceness. At +15 two busy workers on a 2-vCPU box lost their cores to every nice-0 process
# (measured in docs/benchmarks.md, "Fleet calibration").
LOCAL_RAY_CONFIG = {"worker_niceness": 0}
MAX_SOCKET_DIR = 60  # Ray's unix sockets live under the temp dir; their paths must stay < 108 chars


def _failure(job: Job, e: BaseException, wall_s: float | None = None, retries: int = 0, logs: str = "") -> dict:
    """A job's outcome after a system failure (a worker that died, an OSError) its ``retries`` did not cure; ``logs``:
    where the engine's worker logs are (Ray's), said in the reason."""
    tried = f"after {retries} retr{'y' if retries == 1 else 'ies'}" if retries else "(no retry allowed: --retries 0)"
    where = f"; the workers' logs: {logs}" if logs else ""
    return {"id": job.id, "state": "failed", "reason": f"system failure {tried}: {type(e).__name__}: {e}{where}",
            "file": getattr(e, "filename", None), "wall_s": wall_s, "host": socket.gethostname(), "result": None}


def _say_worker_died(ids: list[str]) -> None:
    """One line on stderr per dead worker, naming the jobs it took with it (probe 91: a worker killed by the OOM
    killer was retried without a word; only the attempt counts rose)."""
    import sys

    print(f"fleet: a worker process died (killed, or out of memory) while running {', '.join(ids)}: handed out again "
          "(each alone until one finishes, so the one that killed it is known)", file=sys.stderr)


def run_engine(engine: str, jobs: list[Job], on_start: Callable[[list[str]], object],
               on_outcome: Callable[[dict], object], workers: int = 1, address: str | None = None,
               temp_dir: str | Path | None = None, retries: int = 2, in_flight: int | None = None,
               object_store_mb: int = 200) -> None:
    """Run ``jobs`` on ``engine`` (module doc); returns when every job has an outcome."""
    if engine not in ENGINES:
        raise OptionError("--engine", f"{engine!r} is not an engine; valid: {ENGINES}")
    if not jobs:
        return
    in_flight = max(1, in_flight or 2 * workers)
    if engine == "local":
        return _run_local(jobs, on_start, on_outcome, retries)
    if engine == "process":
        return _run_process(jobs, on_start, on_outcome, workers, retries, in_flight)
    return _run_ray(jobs, on_start, on_outcome, workers, address, temp_dir, retries, in_flight, object_store_mb)


def _run_local(jobs, on_start, on_outcome, retries):
    for job in jobs:
        on_start([job.id])
        for _ in range(retries + 1):
            t0 = time.perf_counter()
            try:
                out = run_job(job.to_dict())
                break
            except OSError as e:  # transient I/O: retried; anything else is a bug and propagates
                out = _failure(job, e, time.perf_counter() - t0, retries)
        on_outcome(out)


def _init_worker(threads: int) -> None:
    os.environ["TQDM_DISABLE"] = "1"  # one progress bar: the driver's
    set_threads(threads)


def _init_pool_worker(threads: int) -> None:
    from hybrid_calib.atomic import best_effort_stderr, exit_with_parent

    _init_worker(threads)
    exit_with_parent()
    best_effort_stderr()  # a spawned worker's own stderr: a note there must not fail the job (probe 70)


def _remote_job(job: dict) -> dict:
    """``run_job`` in a Ray worker (a joined cluster's workers do not inherit ``_worker_env``)."""
    _init_worker(job["threads"])
    return run_job(job)


THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


@contextmanager
def _worker_env(threads: int, extra: dict[str, str] | None = None) -> Iterator[None]:
    """This process's environment with ``THREAD_VARS`` = ``threads``, ``TQDM_DISABLE`` and ``extra``
    while workers are started from it (they inherit it); restored afterwards. This process's own
    libraries are already loaded: they keep their threads."""
    new = {**dict.fromkeys(THREAD_VARS, str(int(threads))), "TQDM_DISABLE": "1", **(extra or {})}
    old = {k: os.environ.get(k) for k in new}
    os.environ.update(new)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _run_process(jobs, on_start, on_outcome, workers, retries, in_flight):
    threads = jobs[0].threads
    # workers are spawned at submit and when a broken pool is rebuilt; multiprocessing's resource tracker (started
    # with the pool, from this environment) warned of "leaked semaphore objects" after a worker was killed or
    # stopped by Ctrl-C: the pool's own queue lock, nothing of ours, and the next run is not affected
    quiet = {"PYTHONWARNINGS": ",".join(filter(None, (os.environ.get("PYTHONWARNINGS"),
                                                      "ignore::UserWarning:multiprocessing.resource_tracker")))}
    with _worker_env(threads, quiet):
        _process_loop(jobs, on_start, on_outcome, workers, retries, in_flight, threads)


def tracker_ignoring_hangup() -> None:
    """Start multiprocessing's resource tracker (once) with SIGHUP ignored, which it keeps across its exec: it ignores
    SIGINT and SIGTERM itself, and a closed terminal's SIGHUP to the process group killed it mid-fleet, its relaunch
    printing "process died unexpectedly" and five KeyError tracebacks (probe 121), while the driver stops the run as
    SIGTERM does."""
    import signal
    import threading
    from multiprocessing import resource_tracker

    hup = getattr(signal, "SIGHUP", None)
    if hup is None or threading.current_thread() is not threading.main_thread():
        resource_tracker.ensure_running()
        return
    before = signal.signal(hup, signal.SIG_IGN)
    try:
        resource_tracker.ensure_running()
    finally:
        signal.signal(hup, before)


def _process_loop(jobs, on_start, on_outcome, workers, retries, in_flight, threads):
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    queue = list(jobs)
    tries: dict[str, int] = {}
    # jobs on a pool whose worker died: one of them killed it, but which is unknown, so none is charged a try; each
    # then runs alone, where a crash is its own (one killed worker had cost every queued vehicle a try)
    suspects: set[str] = set()
    ctx = multiprocessing.get_context("spawn")
    workers = max(1, min(workers, len(queue)))  # no idle process started
    tracker_ignoring_hangup()
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_init_pool_worker, initargs=(threads,))
    running: dict = {}
    try:
        while queue or running:
            while queue and len(running) < in_flight and not (running and (
                    queue[0].id in suspects or any(j.id in suspects for j, _ in running.values()))):
                job = queue.pop(0)
                running[pool.submit(run_job, job.to_dict())] = (job, time.perf_counter())
                on_start([job.id])
            alone = len(running) == 1
            done, _ = wait(list(running), return_when=FIRST_COMPLETED)
            broken, lost = False, []
            for fut in done:
                job, t0 = running.pop(fut)
                try:
                    out = fut.result()
                except BrokenProcessPool as e:  # a worker died (killed, out of memory): retry elsewhere
                    broken, err = True, e
                    lost.append(job.id)
                    if not alone:  # not known to be this job's doing: run it alone, uncharged
                        suspects.add(job.id)
                        queue.insert(0, job)
                        continue
                except OSError as e:
                    err = e
                else:
                    suspects.discard(job.id)
                    on_outcome(out)
                    continue
                tries[job.id] = tries.get(job.id, 0) + 1
                if tries[job.id] > retries:
                    on_outcome(_failure(job, err, time.perf_counter() - t0, retries))
                else:
                    queue.insert(0, job)
            if broken:  # every job still on the dead pool is lost with it: requeue them too, as suspects
                _say_worker_died(lost + [j.id for j, _ in running.values()])
                for fut, (job, _) in running.items():
                    fut.cancel()
                    suspects.add(job.id)
                    queue.insert(0, job)
                running.clear()
                pool.shutdown(wait=False, cancel_futures=True)
                pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_init_pool_worker,
                                           initargs=(threads,))
    except KeyboardInterrupt:  # Ctrl-C: stop now. The workers took the interrupt too and went on to the job already
        _stop_workers(pool)  # queued for them (a whole extra vehicle ran before the exit); the next run redoes theirs
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _stop_workers(pool) -> None:
    """Terminate a process pool's workers (``ProcessPoolExecutor`` has no public way to; its ``_processes``)."""
    for proc in list((getattr(pool, "_processes", None) or {}).values()):
        try:
            proc.terminate()
        except (OSError, AttributeError):  # already gone
            pass


def check_ray_temp(temp_dir: str | Path) -> Path:
    """``temp_dir`` resolved, checked short enough for Ray's socket paths (``OptionError`` if not); nothing created.
    Counted in bytes, as the socket's limit is (probe 66: a 47-character name of 107 bytes passed, and Ray failed
    with an internal error after the manifest was written)."""
    p = Path(temp_dir).resolve()
    if (n := len(os.fsencode(p))) > MAX_SOCKET_DIR:
        raise OptionError("--ray-temp", f"{p} is {n} bytes; Ray's socket paths under it would pass the 107-byte "
                                        f"limit: pass a directory of <= {MAX_SOCKET_DIR} bytes (characters, in ASCII)")
    return p


def ray_temp_dir(temp_dir: str | Path) -> Path:
    """``temp_dir`` checked (``check_ray_temp``) and created."""
    p = check_ray_temp(temp_dir)
    p.mkdir(parents=True, exist_ok=True)
    return p


def _local_ray_env(tmp: Path, token: bool = True) -> None:
    """Keep a local Ray's files under ``tmp``: its temp files (``RAY_TMPDIR``, ``TMPDIR`` of the raylet
    and workers) and its authentication token (``tmp/auth_token`` through ``RAY_AUTH_TOKEN_PATH``,
    instead of ``~/.ray/auth_token``), unless the user set Ray's authentication variables or ``token``
    is False (Ray already imported in this process: it has read its authentication mode)."""
    import secrets

    os.environ["RAY_TMPDIR"] = os.environ["TMPDIR"] = str(tmp)
    if token and not any(v in os.environ for v in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH")):
        token = tmp / "auth_token"
        if not token.is_file():  # created owner-only: never readable by others, not even before a chmod
            fd = os.open(token, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            with os.fdopen(fd, "w") as f:
                f.write(secrets.token_hex(32))
        os.environ["RAY_AUTH_MODE"], os.environ["RAY_AUTH_TOKEN_PATH"] = "token", str(token)


def check_ray_address(address: str, timeout_s: float = 5.0) -> None:
    """``OptionError`` naming ``--address`` when a ``[ray://]HOST:PORT`` head cannot be reached (a TCP
    connect within ``timeout_s``); ``auto`` is left to Ray."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit():
        if address != "auto":
            raise OptionError("--address", f"{address!r} is not HOST:PORT (e.g. 10.0.0.5:6379) or 'auto'")
        return
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as e:
        raise OptionError("--address", f"cannot reach a Ray head at {address} ({e.strerror or e}); start one there "
                                       "with `ray start --head --port PORT`, or check the host and port") from None


def start_ray(workers: int, address: str | None, temp_dir: str | Path | None, object_store_mb: int,
              threads: int = 1) -> bool:
    """Join the cluster at ``address``, or start a local one of ``workers`` CPUs (module doc) whose
    raylet and workers inherit ``_worker_env(threads)``. Returns whether this call started Ray (then
    the caller shuts it down). A Ray already initialised in this process is reused."""
    import importlib.util
    import sys

    if importlib.util.find_spec("ray") is None:
        raise OptionError("--engine", "ray is not installed; pip install -e .[fleet] (or use --engine process)")
    if "ray" in sys.modules and sys.modules["ray"].is_initialized():
        return False
    if address:
        check_ray_address(address)  # Ray itself retries an unreachable head for minutes
    fresh = "ray" not in sys.modules  # Ray reads its authentication mode once, at import
    if not address and temp_dir is not None:
        tmp = ray_temp_dir(temp_dir)
        _local_ray_env(tmp, token=fresh)
    import ray

    # the workers import this checkout of hybrid_calib (not another installed copy)
    root = str(Path(__file__).resolve().parents[2])
    os.environ["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [os.environ.get("PYTHONPATH")])])
    if address:
        with _own_signal_handlers():
            ray.init(address=address, log_to_driver=False)
        return True
    if temp_dir is None:
        raise OptionError("--ray-temp", "a local Ray cluster needs a temp directory")
    # Ray's settings: as variables (``RAY_<name>``, read by the raylet at its start; ``_system_config``
    # alone left workers it started on demand at +15, measured) unless the user set them
    config = {k: v for k, v in LOCAL_RAY_CONFIG.items() if f"RAY_{k}" not in os.environ}
    with _worker_env(threads, {f"RAY_{k}": str(v) for k, v in config.items()}), _own_signal_handlers():
        ray.init(num_cpus=workers, object_store_memory=int(object_store_mb) * 1024 * 1024, _temp_dir=str(tmp),
                 include_dashboard=False, log_to_driver=False, _system_config=config)
    return True


@contextmanager
def _own_signal_handlers() -> Iterator[None]:
    """The process's SIGTERM and SIGINT handlers as they were before the block: ``ray.init`` replaces SIGTERM's with
    ``sys.exit(15)`` (and its core a handler that prints a stack), so a fleet on Ray that got SIGTERM ended with no
    word, an internal-error status or its lock left behind (probe 91); the command's own handler says what it kept and
    exits 143, as on the other engines. Only the main thread can set handlers: elsewhere the block runs as it is."""
    import signal
    import threading

    main = threading.current_thread() is threading.main_thread()
    saved = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)} if main else {}
    try:
        yield
    finally:
        for sig, handler in saved.items():
            if handler is not None:
                signal.signal(sig, handler)


def _run_ray(jobs, on_start, on_outcome, workers, address, temp_dir, retries, in_flight, object_store_mb):
    started = start_ray(workers * jobs[0].threads, address, temp_dir, object_store_mb, jobs[0].threads)
    import ray  # after start_ray: it sets Ray's environment first
    if address:  # a joined cluster is sized by its nodes, not by --workers: keep every CPU fed
        in_flight = max(in_flight, 2 * int(ray.cluster_resources().get("CPU", 0)) // jobs[0].threads)
    try:
        task = ray.remote(num_cpus=jobs[0].threads, max_retries=retries, retry_exceptions=[OSError])(_remote_job)
        queue = list(jobs)
        running: dict = {}
        while queue or running:
            while queue and len(running) < in_flight:
                job = queue.pop(0)
                running[task.remote(job.to_dict())] = (job, time.perf_counter())
                on_start([job.id])
            ready, _ = ray.wait(list(running), num_returns=1)
            for ref in ready:
                job, t0 = running.pop(ref)
                try:
                    on_outcome(ray.get(ref))
                except (ray.exceptions.RayError, OSError) as e:  # retries spent
                    logs = "" if address else str(ray_temp_dir(temp_dir) / "session_latest" / "logs")
                    on_outcome(_failure(job, e, time.perf_counter() - t0, retries, logs))
    finally:
        if started:  # Ray's shutdown leaves SIGTERM at its default: a SIGTERM then ended the run without a word, its
            with _own_signal_handlers():  # line in runs.json, its summary or its lock released (probe 111)
                ray.shutdown()
