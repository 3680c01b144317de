"""The dask side of :func:`curbside.evaluate.runner.run_all`: a local cluster that Ctrl-C stops at any
moment (its start-up included) without worker tracebacks, and an existing scheduler checked in seconds.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
from collections.abc import Callable, Iterator
from typing import Any

from curbside.errors import CurbsideInputError

#: Seconds a dask worker process is given to exit at shutdown. Finalising a worker's interpreter
#: (numba, shapely, pandas) takes 1-2 s alone and more on a loaded machine, past the nanny's default
#: of 4 s, which then logs "Worker process still alive ... killing" and kills it.
WORKER_CLOSE_TIMEOUT_S = 60.0
#: Seconds ``--scheduler`` is given to answer, instead of dask's 30 s connect timeout (a scheduler on a
#: reachable host answers in milliseconds).
SCHEDULER_TIMEOUT_S = 5.0


def start_local_cluster(workers: int):
    """A :class:`dask.distributed.LocalCluster` of ``workers`` processes, started by a thread that blocks
    SIGINT, which its worker processes inherit.

    Ctrl-C then stops the command alone, which closes its workers, instead of printing every worker's
    KeyboardInterrupt traceback; and this thread keeps SIGINT, so a Ctrl-C while the workers start (2-3 s)
    is caught at once (it used to be ignored then, and lost). The cluster is closed, once up, before
    KeyboardInterrupt propagates: a LocalCluster cut short while it starts would leave workers behind.
    """
    from multiprocessing import resource_tracker

    from dask.distributed import LocalCluster

    started: dict[str, Any] = {}
    done = threading.Event()

    def start() -> None:
        try:
            started["cluster"] = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                # no dashboard; the scheduler's HTTP routes on a free port, not 8787 (often taken)
                dashboard_address=":0",
                scheduler_kwargs={"dashboard": False},
                silence_logs=logging.WARNING,
            )
        except BaseException as exc:  # noqa: BLE001 - raised again in the caller's thread
            started["error"] = exc
        finally:
            done.set()

    # multiprocessing's resource tracker unblocks SIGINT in the thread that starts it, which would be the
    # one that starts the first worker: it starts here instead, in a thread that keeps SIGINT anyway.
    resource_tracker.ensure_running()
    thread = threading.Thread(target=start, name="curbside-dask-start", daemon=True)
    try:
        with ctrl_c_blocked():
            thread.start()
        done.wait()
    except KeyboardInterrupt:
        if thread.ident is not None:
            done.wait()
            if "cluster" in started:
                kill_cluster(started["cluster"])
        raise
    if "error" in started:
        raise started["error"]
    return started["cluster"]


@contextlib.contextmanager
def ctrl_c_blocked() -> Iterator[None]:
    """Block SIGINT in this thread (the threads and processes it starts inherit the mask); a Ctrl-C
    meanwhile is held, and raised as KeyboardInterrupt when the block ends. The main thread's handler only
    notes it meanwhile: the mask alone does not hold a Ctrl-C that another thread (tqdm's monitor) takes."""
    held: list[int] = []
    in_main = threading.current_thread() is threading.main_thread()
    handler = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum)) if in_main else None
    masked = hasattr(signal, "pthread_sigmask")  # Windows has no signal masks
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}) if masked else None
    try:
        yield
    finally:
        if masked:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)
        if in_main:
            signal.signal(signal.SIGINT, signal.default_int_handler if handler is None else handler)
            if held:
                raise KeyboardInterrupt


def close_cluster(cluster) -> None:
    """Close a local cluster, each worker process with :data:`WORKER_CLOSE_TIMEOUT_S` to exit on its own."""
    cluster.sync(_close_workers, cluster, WORKER_CLOSE_TIMEOUT_S)
    cluster.close()


def kill_cluster(cluster) -> None:
    """Close a local cluster at once (Ctrl-C): its worker processes are killed, not left to end the runs
    under way (a worker cannot drop a run half-way; a long session's run takes minutes)."""
    silence_distributed()
    cluster.sync(_kill_workers, cluster)
    cluster.close()


async def _kill_workers(cluster) -> None:
    for nanny in list(cluster.workers.values()):
        nanny.close_gracefully(reason="ctrl-c")  # a nanny closing gracefully starts no worker in place
        if (pid := nanny.pid) is not None:
            with contextlib.suppress(ProcessLookupError):  # it exited meanwhile
                os.kill(pid, getattr(signal, "SIGKILL", signal.SIGTERM))  # SIGTERM ends it on Windows


def check_scheduler(address: str) -> None:
    """Refuse a dask scheduler address where none answers within :data:`SCHEDULER_TIMEOUT_S`.

    Parameters
    ----------
    address
        ``[PROTOCOL://]HOST:PORT`` (``--scheduler``).

    Raises
    ------
    CurbsideInputError
        Naming ``--scheduler``: a closed port (at once), a host that does not answer, a server that is
        not a dask scheduler.
    """
    try:
        _probe_scheduler(address, SCHEDULER_TIMEOUT_S)
    except (OSError, ValueError, TypeError) as exc:
        raise _unreachable(address, exc) from None


def _unreachable(address: str, exc: Exception) -> CurbsideInputError:
    return CurbsideInputError("--scheduler", f"cannot reach a dask scheduler at {address!r} ({exc})")


def connect(scheduler: str):
    """A client of the dask scheduler at ``scheduler``, or :class:`CurbsideInputError` naming the option
    (:func:`check_scheduler`)."""
    from dask.distributed import Client

    check_scheduler(scheduler)
    try:
        return Client(scheduler, timeout=SCHEDULER_TIMEOUT_S)
    except (OSError, ValueError, TypeError) as exc:  # it went away since
        raise _unreachable(scheduler, exc) from None


def _probe_scheduler(address: str, timeout_s: float) -> None:
    """Raise :class:`OSError` unless a dask scheduler at ``address`` answers within ``timeout_s``.

    dask's own connection retries a refused port for 30 s (``distributed.comm.timeouts.connect``) and
    waits without end on a server that accepts but never answers; a server that answers something else
    (an HTTP proxy) fails it with a MemoryError. A TCP connection first refuses a closed port at once.
    What tornado and asyncio log meanwhile is dropped (:data:`_PROBE_LOGGERS`): the error says it.
    """
    import asyncio
    import socket

    from distributed.comm import connect
    from distributed.comm.addressing import get_address_host_port, parse_address
    from distributed.security import Security

    tls = parse_address(address)[0] == "tls"

    async def identity(connection_args: dict[str, Any]) -> object:
        comm = await connect(address, timeout=timeout_s, **connection_args)
        try:
            await comm.write({"op": "identity"})
            return await comm.read()
        finally:
            await comm.close()

    def ask() -> object:
        # the TLS settings of dask's config, as a Client has them (a tls:// scheduler needs them)
        connection_args = Security().get_connection_args("client")
        if tls and connection_args.get("ssl_context") is None:
            raise ValueError(_NO_TLS_SETTINGS)
        try:
            host_port = get_address_host_port(address)
        except ValueError:  # an address without a TCP port (inproc://): dask's connection alone
            pass
        else:
            socket.create_connection(host_port, timeout=timeout_s).close()
        with _unlogged_in_this_thread(_PROBE_LOGGERS):
            return asyncio.run(asyncio.wait_for(identity(connection_args), timeout_s))

    try:
        reply = _in_daemon_thread(ask)  # a thread of its own: asyncio.run fails under a running loop
    except (TimeoutError, asyncio.TimeoutError):
        raise OSError(f"no answer within {timeout_s:g} s") from None
    except Exception as exc:  # noqa: BLE001 - whatever a server that is not dask's makes the reader raise
        if (problem := _handshake_problem(exc, tls)) is not None:
            raise OSError(problem) from None
        if isinstance(exc, (OSError, ValueError, TypeError)):
            raise
        raise OSError(f"what answers is not a dask scheduler ({type(exc).__name__})") from None
    kind = reply.get("type") if isinstance(reply, dict) else None
    if kind != "Scheduler":
        raise OSError(f"what answers is not a dask scheduler but {kind or 'something else'}")


#: Where the probe's failures are logged, as well as raised: tornado logs a failed TLS handshake on
#: tornado.general ("SSL Error on 7 ('127.0.0.1', 8786): [SSL: CERTIFICATE_VERIFY_FAILED] ..."), shown
#: where dask's logging configuration leaves tornado's level alone (its "version: 1" form does); an error
#: in a callback on tornado.application, asyncio one of its loop on asyncio, both with a traceback.
_PROBE_LOGGERS = ("tornado.general", "tornado.application", "asyncio")
_NO_TLS_SETTINGS = ("dask's configuration has no TLS settings for a tls:// scheduler: "
                    "distributed.comm.tls.ca-file, distributed.comm.tls.client.cert and .key")
_NOT_TLS = "what answers does not speak TLS: a tcp:// scheduler?"


@contextlib.contextmanager
def _unlogged_in_this_thread(names: tuple[str, ...]) -> Iterator[None]:
    """Drop what the loggers ``names`` log from this thread meanwhile; other threads' records, and any
    logged afterwards, go through."""
    probe_thread = threading.get_ident()

    def from_another_thread(record: logging.LogRecord) -> bool:
        return record.thread != probe_thread

    loggers = [logging.getLogger(name) for name in names]
    for logger in loggers:
        logger.addFilter(from_another_thread)
    try:
        yield
    finally:
        for logger in loggers:
            logger.removeFilter(from_another_thread)


def _handshake_problem(exc: BaseException, tls: bool) -> str | None:
    """What ``exc`` says went wrong if a TLS handshake failed (``tls``: a tls:// address), or a server
    closed a tcp:// connection unanswered, as a TLS one does; None for any other error. dask says these
    poorly: "" (a plain server), "IOStream is not idle; cannot convert to SSL" (a plain server that
    spoke first, as a tcp:// dask scheduler does), "in <TCP (closed) local=... remote=...>:
    ConnectionResetError ..." (a TLS server)."""
    import ssl

    from distributed.comm.core import CommClosedError

    cause: BaseException | None = exc
    while cause is not None:
        if isinstance(cause, ssl.SSLCertVerificationError):
            return (f"its TLS certificate fails verification: {cause.verify_message}; "
                    "distributed.comm.tls.ca-file of dask's configuration names the CAs trusted")
        if isinstance(cause, ssl.SSLError):
            if cause.reason == "WRONG_VERSION_NUMBER":
                return _NOT_TLS
            return f"the TLS handshake failed: {cause.reason or cause}"
        cause = cause.__cause__
    if tls and isinstance(exc, ValueError) and "not idle" in str(exc):
        return _NOT_TLS
    if not tls and isinstance(exc, CommClosedError):
        return "it closed the connection unanswered, as a TLS scheduler does: a tls:// one?"
    return None


def _in_daemon_thread(work: Callable[[], Any]) -> Any:
    """``work()``'s result (or error) from a daemon thread. A Ctrl-C ends the wait at once: neither a
    thread pool's shutdown nor the interpreter's exit waits for the thread, up to 10 s on a silent host."""
    outcome: dict[str, Any] = {}

    def run() -> None:
        try:
            outcome["result"] = work()
        except BaseException as exc:  # noqa: BLE001 - raised again in the caller's thread
            outcome["error"] = exc

    thread = threading.Thread(target=run, name="curbside-scheduler-probe", daemon=True)
    thread.start()
    thread.join()
    if "error" in outcome:
        raise outcome["error"]
    return outcome["result"]


class HeartbeatAtShutdown(logging.Filter):
    """Drops the noise of a worker whose cluster is closing: "Failed to communicate with scheduler during
    heartbeat" (and its traceback), and, after Ctrl-C, "Async instruction ... ended with CancelledError".

    When a local cluster closes, a worker's heartbeat can race the scheduler's exit and log that error,
    a traceback at the end of a run that succeeded; Ctrl-C cancels the tasks under way, which each
    worker logs. A scheduler that dies mid-run still fails the run through its futures.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        return "during heartbeat" not in message and "ended with CancelledError" not in message


def _drop_every_record(record: logging.LogRecord) -> bool:
    return False


def silence_distributed() -> None:
    """Drop whatever dask logs from now on in this process: after Ctrl-C the scheduler's broadcasts to the
    workers being killed fail, and dask logs each, with tracebacks, under "localize: interrupted"."""
    for handler in logging.getLogger("distributed").handlers:
        handler.addFilter(_drop_every_record)  # once per handler, however often it is called


def quiet_heartbeat_at_shutdown() -> None:
    for name in ("distributed.worker", "distributed.worker.state_machine"):
        logging.getLogger(name).addFilter(HeartbeatAtShutdown())


async def _close_workers(cluster, timeout_s: float) -> None:
    """Close a local cluster's worker processes, each with ``timeout_s`` to exit on its own."""
    import asyncio

    await asyncio.gather(*(w.close(timeout=timeout_s) for w in list(cluster.workers.values())))
