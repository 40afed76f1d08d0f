"""Running the server: HTTP processes sized to the cores, and a job worker beside them.

``posefix serve`` and ``posefix demo`` call ``run_server``. With one HTTP process the
app runs in this process, its job worker (when asked for) as a thread woken by each
commit. With several (the default on a multi-core machine, SQLite included: WAL lets
readers run beside the one writer, and every writing transaction takes the lock up
front), uvicorn starts them from ``app_from_environment``, and the job worker runs as its
own ``posefix worker`` process, so an hour-long solve never holds an HTTP process's
interpreter. Previews and other CPU-bound requests run on threads of each HTTP process,
never on its event loop.

Settings reach the child processes through the environment (``POSEFIX_*``), so a caller
passes its overrides in ``env``.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys

from posefix.config import Settings


def default_http_processes() -> int:
    """One HTTP process per core this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def app_from_environment():  # type: ignore[no-untyped-def]
    """The uvicorn factory of each HTTP process (no job worker: that is its own process)."""
    from posefix.main import create_app

    return create_app(Settings(), embedded_worker=False)


def _die_with_parent() -> None:
    """In the child: SIGTERM when the parent dies, even by SIGKILL (Linux prctl; elsewhere nothing)."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def start_job_worker() -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", "from posefix.cli import main; main(['worker'])"],
                            preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None)


def stop_job_worker(proc: subprocess.Popen, timeout_s: float = 30.0) -> None:
    """SIGTERM (the worker finishes its job), then wait; kill it if it does not stop."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def run_server(settings: Settings, *, host: str, port: int, processes: int, job_worker: bool, keep_alive_s: int = 75,
               env: dict[str, str] | None = None) -> None:
    """Serve until stopped: ``processes`` HTTP processes and, if ``job_worker``, a job worker."""
    import uvicorn

    common = dict(host=host, port=port, proxy_headers=True, log_config=None, timeout_keep_alive=keep_alive_s)
    if processes <= 1:
        from posefix.main import create_app

        uvicorn.run(create_app(settings, embedded_worker=job_worker), **common)
        return
    os.environ.update(env or {})
    worker = start_job_worker() if job_worker else None
    try:
        uvicorn.run("posefix.serving:app_from_environment", factory=True, workers=processes, **common)
    finally:
        if worker is not None:
            stop_job_worker(worker)
