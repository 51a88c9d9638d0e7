"""Where suite tasks run: a local process pool, or Ray.

Both backends take module-level functions of one picklable argument that never
raise (they return an error record instead) and offer the same small interface
(`Executor`). Workers are fresh interpreters (spawn; Ray's own workers), never
forks of a process that holds an OpenGL context, and every worker gets the same
environment (`worker_env`): PYOPENGL_PLATFORM=osmesa and thread counts that
share the CPUs between workers, so both backends compute the same numbers.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os
import signal
from collections.abc import Callable, Iterable
from typing import Any

EXECUTORS = ("local", "ray")
_THREAD_VARS = ("LP_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


class ExecutorError(RuntimeError):
    """An executor that cannot be started (unknown name, Ray missing or unreachable)."""


def available_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def worker_env(workers: int) -> dict[str, str]:
    """Environment of every worker: OSMesa, and CPUs / workers threads each."""
    threads = str(max(1, available_cpus() // max(1, workers)))
    env = {"PYOPENGL_PLATFORM": "osmesa"}
    for var in _THREAD_VARS:
        env[var] = os.environ.get(var, threads)
    return env


def apply_worker_env(env: dict[str, str]) -> None:
    """Set ``env`` in this worker (before OpenGL, numpy or OpenCV do their set-up)."""
    os.environ.update(env)
    try:
        import cv2

        cv2.setNumThreads(int(env.get("OMP_NUM_THREADS", "1")))
    except ImportError:
        pass


def _local_init(env: dict[str, str]) -> None:
    apply_worker_env(env)
    # the parent handles Ctrl-C (it stops the pool); a worker dies with its parent
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _die_with_parent()


def _die_with_parent() -> None:
    """Linux: SIGKILL this process when its parent dies (a killed suite leaves no orphan)."""
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        PR_SET_PDEATHSIG = 1
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
        if os.getppid() == 1:  # the parent is already gone
            os._exit(1)
    except (OSError, AttributeError):
        pass


class Executor:
    """Run ``fn(arg)`` tasks; handles are opaque."""

    name = "base"

    def submit(self, fn: Callable[[Any], Any], arg: Any) -> Any:
        raise NotImplementedError

    def wait(self, handles: Iterable[Any]) -> list[Any]:
        """Block until at least one handle is done; return the done ones."""
        raise NotImplementedError

    def result(self, handle: Any) -> Any:
        """The task's return value; raises if the worker itself died."""
        raise NotImplementedError

    def shutdown(self, kill: bool = False) -> None:
        raise NotImplementedError


class LocalExecutor(Executor):
    """A ``ProcessPoolExecutor`` of spawned workers (a broken pool is replaced)."""

    name = "local"

    def __init__(self, workers: int) -> None:
        self.workers = workers
        self.env = worker_env(workers)
        self._pool = self._new_pool()

    def _new_pool(self) -> cf.ProcessPoolExecutor:
        return cf.ProcessPoolExecutor(
            max_workers=self.workers,
            mp_context=mp.get_context("spawn"),
            initializer=_local_init,
            initargs=(self.env,),
        )

    def submit(self, fn, arg):
        try:
            return self._pool.submit(fn, arg)
        except cf.process.BrokenProcessPool:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = self._new_pool()
            return self._pool.submit(fn, arg)

    def wait(self, handles):
        done, _ = cf.wait(list(handles), return_when=cf.FIRST_COMPLETED)
        return list(done)

    def result(self, handle):
        return handle.result()

    def shutdown(self, kill: bool = False) -> None:
        if kill:
            procs = list(getattr(self._pool, "_processes", {}).values())
            self._pool.shutdown(wait=False, cancel_futures=True)
            for p in procs:
                if p.is_alive():
                    p.kill()
            for p in procs:
                p.join(timeout=5)
        else:
            self._pool.shutdown(wait=True)


class RayExecutor(Executor):
    """Ray tasks (one CPU each): a local instance of ``workers`` CPUs, or ``address``.

    With ``address`` the cluster's workers must see the same paths (suite folder,
    render cache) as this machine: a shared file system.
    """

    name = "ray"

    def __init__(self, workers: int, address: str | None = None) -> None:
        try:
            import ray
        except ImportError:
            raise ExecutorError(
                "executor 'ray' needs the ray package: pip install 'ray>=2.9'"
            ) from None
        self._ray = ray
        self.env = worker_env(workers)
        self._started = False  # True when this executor started Ray (and stops it)
        runtime_env = {"env_vars": self.env}
        if not ray.is_initialized():
            try:
                if address:
                    ray.init(address=address, runtime_env=runtime_env, log_to_driver=False)
                else:
                    ray.init(
                        num_cpus=workers,
                        runtime_env=runtime_env,
                        include_dashboard=False,
                        log_to_driver=False,
                        configure_logging=False,
                    )
            except (ConnectionError, RuntimeError, ValueError) as e:
                raise ExecutorError(
                    f"cannot start or reach Ray (address {address!r}): {e}"
                ) from None
            self._started = True
        self._remote: dict[Callable, Any] = {}

    def submit(self, fn, arg):
        if fn not in self._remote:
            self._remote[fn] = self._ray.remote(num_cpus=1, max_retries=0)(_ray_call).options(
                name=fn.__name__
            )
        return self._remote[fn].remote(fn, arg, self.env)

    def wait(self, handles):
        done, _ = self._ray.wait(list(handles), num_returns=1)
        return done

    def result(self, handle):
        return self._ray.get(handle)

    def shutdown(self, kill: bool = False) -> None:
        if self._started:
            self._ray.shutdown()


def _ray_call(fn: Callable[[Any], Any], arg: Any, env: dict[str, str]) -> Any:
    apply_worker_env(env)
    return fn(arg)


def check_executor(name: str, address: str | None = None) -> None:
    """Raise ExecutorError for an unknown executor or an address it cannot use."""
    if name not in EXECUTORS:
        raise ExecutorError(f"unknown executor {name!r}; choose one of {', '.join(EXECUTORS)}")
    if name == "local" and address:
        raise ExecutorError("--address is for the 'ray' executor")


def make_executor(name: str, workers: int, address: str | None = None) -> Executor:
    check_executor(name, address)
    if name == "ray":
        return RayExecutor(workers, address)
    return LocalExecutor(workers)
