"""``localize evaluate`` / ``localize benchmark`` on dask: a Ctrl-C while the local cluster's workers
start ends the command at once (exit status 130, one line, no worker left behind), as one during the
runs does, without waiting for the runs under way (their workers are killed; on ``--scheduler`` they are
cancelled and the user's cluster lives on); and a ``--scheduler`` where no dask scheduler answers is
refused in seconds (exit status 2), not after dask's 30 s connect timeout, nor never (a server that
accepts and stays silent)."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import psutil
import pytest

from curbside.cli.localize import main
from curbside.errors import CurbsideInputError
from curbside.evaluate import dask_cluster, runner, suite

MAP = Path(__file__).parent / "data" / "evaluate" / "sf-path3.geojson"

#: ``localize`` with a line on stderr when the LocalCluster starts (``@starting``) and when the runs
#: are handed to the workers (``@running``), so that the test knows when to press Ctrl-C; with
#: ``SLOW_RUN_S`` in its environment, each run first sleeps that long (a long session's run), but the run
#: of a session named ``broken`` fails at once.
_CHILD = textwrap.dedent(
    """
    import os
    import sys
    import time

    import distributed

    from curbside.cli.localize import main
    from curbside.evaluate import runner

    if os.environ.get("SLOW_RUN_S"):
        run_one, slow_s = runner.run_one, float(os.environ["SLOW_RUN_S"])

        def slow_run_one(spec):  # defined in __main__: dask ships it to the workers by value
            if os.path.basename(spec.session) == "broken":
                raise RuntimeError("this run fails")
            time.sleep(slow_s)
            return run_one(spec)

        runner.run_one = slow_run_one

    def say(moment):
        sys.stderr.write(f"@{moment}\\n")
        sys.stderr.flush()

    start, submit = distributed.LocalCluster.__init__, distributed.Client.map

    def starting(self, *args, **kwargs):
        say("starting")
        start(self, *args, **kwargs)

    def running(self, *args, **kwargs):
        futures = submit(self, *args, **kwargs)
        say("running")
        return futures

    distributed.LocalCluster.__init__, distributed.Client.map = starting, running
    sys.exit(main(sys.argv[1:]))
    """
)


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    """One simulated walk of the benchmark's path 3 (the fixture map is clipped around it)."""
    folder = tmp_path_factory.mktemp("walks") / "path3-s1"
    assert main(["simulate", "--route", "path3", "--seed", "1", "--map", str(MAP), "-o", str(folder)]) == 0
    return folder


def _alive_in_session(session_id: int) -> list[str]:
    """The processes of a session (a command and its workers) that are still running (not zombies)."""
    alive = []
    for proc in psutil.process_iter(["status", "cmdline"]):
        with contextlib.suppress(psutil.Error, OSError):
            if os.getsid(proc.pid) == session_id and proc.info["status"] != psutil.STATUS_ZOMBIE:
                alive.append(" ".join(proc.info["cmdline"] or []))
    return alive


def _read_up_to(stream, mark: bytes) -> bytes:
    """Read ``stream`` up to the line ``mark``; what came before it."""
    seen = b""
    for line in iter(stream.readline, b""):
        if line.rstrip() == mark:
            return seen
        seen += line
    raise AssertionError(f"the command ended before {mark.decode()}: {seen.decode()}")


def _interrupt(
    tmp_path: Path, argv: list[str], moment: str, delay_s: float, slow_run_s: float = 0.0,
    again_s: float | None = None, child: str = _CHILD,
):
    """Run ``localize ARGV`` in a session of its own, SIGINT its process group ``delay_s`` after
    ``@moment`` (and again ``again_s`` later); its exit status, stderr, seconds from the (first) SIGINT to
    its exit, processes left running."""
    env = {**os.environ, "SLOW_RUN_S": str(slow_run_s) if slow_run_s else ""}
    proc = subprocess.Popen([sys.executable, "-c", child, *argv], cwd=tmp_path, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, start_new_session=True, env=env)
    try:
        _read_up_to(proc.stderr, f"@{moment}".encode())
        time.sleep(delay_s)
        os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: to the command and its workers
        sent = time.monotonic()
        if again_s is not None:
            time.sleep(again_s)
            os.killpg(proc.pid, signal.SIGINT)
    except BaseException:
        _finish(proc)
        raise
    err, ended, left = _finish(proc)
    return proc.returncode, err.decode(), ended - sent, left


def _finish(proc: subprocess.Popen) -> tuple[bytes, float, list[str]]:
    """Wait for a command started in a session of its own: its stderr, when it exited, and the processes
    of its session still running a few seconds later (then killed)."""
    try:
        _, err = proc.communicate(timeout=90)
        ended = time.monotonic()
        deadline = ended + 5  # multiprocessing's resource tracker exits after the command
        while (left := _alive_in_session(proc.pid)) and time.monotonic() < deadline:
            time.sleep(0.2)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
    return err, ended, left


def _assert_interrupted(status: int, text: str, statuses: tuple[int, ...] = (130,)) -> None:
    assert status in statuses, text
    assert text.splitlines()[-1] == "localize: interrupted" and text.count("interrupted") == 1, text
    assert "Traceback" not in text and "KeyboardInterrupt" not in text and "distributed." not in text, text


def _evaluate_argv(session: Path, out: Path, *parallel: str) -> list[str]:
    return ["evaluate", str(session), "--maps", str(MAP), "--methods", "gnss", "fused", "--jaywalk-weights",
            "0.4", *parallel, "-o", str(out)]


@pytest.mark.slow
@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to a process group is POSIX")
@pytest.mark.parametrize(
    ("moment", "delay_s", "slow_run_s", "again_s", "limit_s"),
    # under way, runs of 30 s (a long session's) are dropped: the workers are killed (it took 38.6 s); a
    # second Ctrl-C while they are killed (a tenth of a second) does not cut that short (it took 6-11 s,
    # with "Worker process still alive" warnings)
    [("starting", 0.2, 0, None, 10), ("starting", 1.0, 0, None, 10), ("running", 1.5, 30, None, 8),
     ("running", 1.5, 30, 0.02, 8)],
    ids=["workers-starting-0.2s", "workers-starting-1s", "30s-runs-under-way", "twice-while-killing"],
)
def test_ctrl_c_ends_a_dask_run_at_once(tmp_path, session, moment, delay_s, slow_run_s, again_s, limit_s):
    out = tmp_path / "report"
    status, text, exit_s, left = _interrupt(
        tmp_path, _evaluate_argv(session, out, "--workers", "2"), moment, delay_s, slow_run_s, again_s
    )
    # a second Ctrl-C that comes once the command is done may end the interpreter's exit (killed by SIGINT)
    _assert_interrupted(status, text, (130,) if again_s is None else (130, -signal.SIGINT))
    assert exit_s < limit_s, f"{exit_s:.1f} s from Ctrl-C to the exit"
    assert not left, f"left running: {left}"
    assert not out.exists()


@pytest.mark.slow
def test_a_run_that_fails_stops_the_others_at_once(tmp_path, session):
    """The failing run's error comes within seconds, not once the other runs end (30 s each here, then
    up to 60 s for the workers to close); no worker is left and no report written."""
    broken = tmp_path / "walks" / "broken"
    shutil.copytree(session, broken)
    out = tmp_path / "report"
    argv = _evaluate_argv(session, out, "--workers", "2")
    argv[1:2] = [str(broken), str(session)]  # the failing runs first: the workers start them at once
    start = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, *argv], cwd=tmp_path, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, env={**os.environ, "SLOW_RUN_S": "30"},
                            start_new_session=True)
    err_bytes, ended, left = _finish(proc)
    err, took_s = err_bytes.decode(), ended - start
    assert proc.returncode not in (0, 130), err
    assert "this run fails" in err, err
    assert took_s < 25, f"{took_s:.1f} s to report a run that failed at once"
    assert not left, f"left running: {left}"
    assert not out.exists()


@pytest.mark.slow
@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to a process group is POSIX")
def test_ctrl_c_cancels_the_runs_on_a_scheduler_and_leaves_its_cluster_up(tmp_path, session):
    from dask.distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0",
                           scheduler_kwargs={"dashboard": False})
    try:
        out = tmp_path / "report"
        argv = _evaluate_argv(session, out, "--scheduler", cluster.scheduler_address)
        status, text, exit_s, left = _interrupt(tmp_path, argv, "running", 1.5, slow_run_s=30)
        with Client(cluster) as client:
            workers = client.scheduler_info()["workers"]
            held = client.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks))
    finally:
        dask_cluster.kill_cluster(cluster)  # its worker would sleep on in the cancelled run
    _assert_interrupted(status, text)
    assert exit_s < 8, f"{exit_s:.1f} s from Ctrl-C to the exit"
    assert not left, f"left running: {left}"
    assert len(workers) == 1 and held == 0, (workers, held)
    assert not out.exists()


@contextlib.contextmanager
def _server(kind: str):
    """A loopback address where no dask scheduler answers: ``closed`` (a port nothing listens on),
    ``unroutable`` (a full accept queue: the connection is never made, as with an address no host
    answers), ``silent`` (accepts, never says a word), ``http`` (answers as an HTTP proxy does)."""
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    address = f"tcp://127.0.0.1:{listener.getsockname()[1]}"
    held: list[socket.socket] = [listener]
    if kind == "closed":
        listener.close()
    elif kind == "unroutable":
        listener.listen(0)
        held.append(socket.create_connection(listener.getsockname()))  # fills the queue: SYNs are dropped
    else:
        listener.listen(8)

        def serve() -> None:
            with contextlib.suppress(OSError):
                while True:
                    conn, _ = listener.accept()
                    held.append(conn)
                    if kind == "http":
                        conn.recv(1024)
                        conn.sendall(b"HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n\r\n")

        threading.Thread(target=serve, daemon=True).start()
    try:
        yield address
    finally:
        for sock in held:
            sock.close()


def _refusal(address: str, limit_s: float) -> tuple[CurbsideInputError, float]:
    """What ``run_all`` on the scheduler at ``address`` raises, and after how long; fails past
    ``limit_s`` (the run waits on in a thread of its own, as it would have for 30 s or for ever)."""
    outcome: dict[str, object] = {}

    def run() -> None:
        start = time.monotonic()
        try:
            runner.run_all([runner.RunSpec("no-session", "gnss")], scheduler=address)
        except Exception as exc:  # noqa: BLE001 - checked below
            outcome["error"] = exc
        outcome["s"] = time.monotonic() - start

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(limit_s)
    assert not thread.is_alive(), f"still waiting for {address} after {limit_s:g} s"
    error = outcome.get("error")
    assert isinstance(error, CurbsideInputError), repr(error)
    assert str(error).startswith(f"--scheduler: cannot reach a dask scheduler at '{address}'"), error
    return error, float(outcome["s"])


#: ``localize`` with a line on stderr (``@probing``) when it starts to probe ``--scheduler``.
_PROBE_CHILD = textwrap.dedent(
    """
    import sys

    from curbside.cli.localize import main
    from curbside.evaluate import dask_cluster

    probe = dask_cluster._probe_scheduler

    def probing(*args):
        sys.stderr.write("@probing\\n")
        sys.stderr.flush()
        return probe(*args)

    dask_cluster._probe_scheduler = probing
    sys.exit(main(sys.argv[1:]))
    """
)


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to a process group is POSIX")
def test_ctrl_c_while_a_silent_scheduler_is_probed_ends_at_once(tmp_path, session):
    """The probe waits up to 5 s for the connection and 5 s for the answer; Ctrl-C does not wait for it
    (it took up to 10 s: the probe's thread was joined on the way out)."""
    with _server("silent") as address:
        argv = _evaluate_argv(session, tmp_path / "report", "--scheduler", address)
        status, text, exit_s, left = _interrupt(tmp_path, argv, "probing", 0.5, child=_PROBE_CHILD)
    _assert_interrupted(status, text)
    assert exit_s < 2, f"{exit_s:.1f} s from Ctrl-C to the exit"
    assert not left, f"left running: {left}"


def test_a_closed_scheduler_port_is_refused_at_once():
    with _server("closed") as address:
        error, took_s = _refusal(address, limit_s=3)
    assert "Connection refused" in str(error) and took_s < 2


@pytest.mark.parametrize("kind", ["unroutable", "silent"])
def test_a_scheduler_that_does_not_answer_is_refused_within_the_timeout(monkeypatch, kind):
    assert dask_cluster.SCHEDULER_TIMEOUT_S <= 5
    monkeypatch.setattr(dask_cluster, "SCHEDULER_TIMEOUT_S", 1.0)  # the test's time, not the default's
    with _server(kind) as address:
        error, took_s = _refusal(address, limit_s=6)
    assert "no answer within 1 s" in str(error) and took_s < 4


def test_a_server_that_is_not_a_dask_scheduler_is_bad_input():
    with _server("http") as address:
        error, _ = _refusal(address, limit_s=6)  # it was a MemoryError, an internal error
    assert "not a dask scheduler" in str(error)


def test_a_running_scheduler_is_accepted_and_a_worker_address_named_for_what_it_is():
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=1, processes=False, protocol="tcp", dashboard_address=":0",
                      scheduler_kwargs={"dashboard": False}) as cluster:
        dask_cluster.check_scheduler(cluster.scheduler_address)
        worker = next(iter(cluster.scheduler_info["workers"]))
        with pytest.raises(CurbsideInputError, match="not a dask scheduler but Worker"):
            dask_cluster.check_scheduler(worker)


def test_evaluate_refuses_an_unreachable_scheduler_before_reading_its_inputs(tmp_path, capsys):
    with _server("closed") as address:
        argv = ["evaluate", str(tmp_path / "no-sessions"), "--maps", str(tmp_path / "no-map.geojson"),
                "--scheduler", address, "-o", str(tmp_path / "report")]
        assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"localize: error: --scheduler: cannot reach a dask scheduler at '{address}'"), err
    assert err.count("\n") == 1 and not (tmp_path / "report").exists()


def test_benchmark_refuses_an_unreachable_scheduler_before_any_walk(tmp_path, capsys, monkeypatch):
    def run_suite(*args, **kwargs):
        raise AssertionError("walks simulated and tracked before --scheduler was checked")

    monkeypatch.setattr(suite, "run_suite", run_suite)
    with _server("closed") as address:
        assert main(["benchmark", "--scheduler", address, "-o", str(tmp_path / "bench")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("localize: error: --scheduler: cannot reach a dask scheduler"), err
    assert not (tmp_path / "bench").exists()
