"""The ``--scheduler`` probe on a TLS mismatch (loopback only): one line naming the address and what is
wrong, and nothing else on stderr. A tls:// address served in plain TCP, a tcp:// address served in TLS,
a TLS certificate the client does not trust, no TLS settings at all. tornado logs each failed TLS
handshake ("SSL Error on 7 ...: [SSL: CERTIFICATE_VERIFY_FAILED] ...") above curbside's own line where
dask's logging configuration leaves tornado's loggers alone, and dask's messages said it poorly ("",
"IOStream is not idle; cannot convert to SSL", "in <TCP (closed) ...>: ConnectionResetError ...")."""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import socket
import ssl
import subprocess
import sys
import textwrap
import threading
from collections.abc import Iterator
from pathlib import Path

import dask
import distributed  # noqa: F401 - its defaults in dask's config before a test sets TLS keys within it
import pytest

from curbside.errors import CurbsideInputError
from curbside.evaluate import dask_cluster

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="needs openssl to make certificates")

_TLS = "distributed.comm.tls"
_NO_TLS = {f"{_TLS}.ca-file": None, f"{_TLS}.client.cert": None, f"{_TLS}.client.key": None}
#: ``localize`` run as the CLI runs it.
_LOCALIZE = "import sys; from curbside.cli.localize import main; sys.exit(main(sys.argv[1:]))"


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> dict[str, Path]:
    """A self-signed certificate for 127.0.0.1 (``cert``, ``key``) and another one (``other``), a CA
    that did not sign it."""
    folder = tmp_path_factory.mktemp("certs")
    paths = {}
    for name, extra in (("", ["-addext", "subjectAltName=DNS:localhost,IP:127.0.0.1"]), ("other-", [])):
        cert, key = folder / f"{name}cert.pem", folder / f"{name}key.pem"
        subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key),
                        "-out", str(cert), "-days", "1", "-subj", "/CN=localhost", *extra],
                       check=True, capture_output=True, timeout=60)
        paths[f"{name}cert"], paths[f"{name}key"] = cert, key
    paths["other"] = paths.pop("other-cert")
    return paths


def _tls_settings(certs: dict[str, Path], ca: str = "cert") -> dict[str, str]:
    """dask's TLS settings of a client that has ``certs``'s certificate and trusts the CA ``ca``."""
    return {f"{_TLS}.ca-file": str(certs[ca]), f"{_TLS}.client.cert": str(certs["cert"]),
            f"{_TLS}.client.key": str(certs["key"])}


@contextlib.contextmanager
def _server(kind: str, certs: dict[str, Path]) -> Iterator[int]:
    """A loopback port served by ``plain`` (reads, then answers an HTTP error) or ``tls`` (a TLS server
    with ``certs``)."""
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(8)
    held = [listener]
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.load_cert_chain(certs["cert"], certs["key"])

    def talk(conn: socket.socket) -> None:
        with contextlib.suppress(OSError):
            if kind == "plain":
                conn.recv(1024)
                conn.sendall(b"HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n\r\n")
            else:
                held.append(tls := context.wrap_socket(conn, server_side=True))
                tls.recv(1024)

    def serve() -> None:
        with contextlib.suppress(OSError):
            while True:
                conn, _ = listener.accept()
                held.append(conn)
                threading.Thread(target=talk, args=(conn,), daemon=True).start()

    threading.Thread(target=serve, daemon=True).start()
    try:
        yield listener.getsockname()[1]
    finally:
        for sock in held:
            sock.close()


@pytest.mark.parametrize(
    ("scheme", "kind", "settings", "problem"),
    [("tls", "plain", "trusted", "what answers does not speak TLS: a tcp:// scheduler?"),
     ("tcp", "tls", "trusted", "it closed the connection unanswered, as a TLS scheduler does: a tls:// one?"),
     ("tls", "tls", "untrusted", "its TLS certificate fails verification: self-signed certificate; "
      "distributed.comm.tls.ca-file of dask's configuration names the CAs trusted"),
     ("tls", "tls", "none", "dask's configuration has no TLS settings for a tls:// scheduler: "
      "distributed.comm.tls.ca-file, distributed.comm.tls.client.cert and .key")],
    ids=["tls-to-plain", "tcp-to-tls", "untrusted-certificate",
         "no-tls-settings"],
)
def test_a_tls_mismatch_is_named_for_what_it_is(certs, scheme, kind, settings, problem):
    config = {"trusted": _tls_settings(certs), "untrusted": _tls_settings(certs, "other"), "none": _NO_TLS}
    with _server(kind, certs) as port, dask.config.set(config[settings]):
        address = f"{scheme}://127.0.0.1:{port}"
        with pytest.raises(CurbsideInputError) as refused:
            dask_cluster.check_scheduler(address)
    assert str(refused.value) == f"--scheduler: cannot reach a dask scheduler at '{address}' ({problem})"


def test_a_tls_probe_of_a_tcp_dask_scheduler_says_it_does_not_speak_tls(certs):
    """A tcp:// dask scheduler speaks first: dask's error was mostly "IOStream is not idle; cannot convert
    to SSL" (its words arrived before the TLS handshake began), else "" (after)."""
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=0, processes=False, protocol="tcp", dashboard_address=":0",
                      scheduler_kwargs={"dashboard": False}, silence_logs=logging.CRITICAL) as cluster:
        address = cluster.scheduler_address.replace("tcp://", "tls://")
        with dask.config.set(_tls_settings(certs)):
            for _ in range(3):  # each of dask's errors, most likely
                with pytest.raises(CurbsideInputError, match="does not speak TLS: a tcp:// scheduler"):
                    dask_cluster.check_scheduler(address)


@pytest.fixture
def tornado_warnings() -> Iterator[list[logging.LogRecord]]:
    """What tornado and asyncio log at WARNING and above, as where dask's logging configuration leaves
    tornado's loggers at their defaults (its ``logging: {version: 1, ...}`` form does)."""
    records: list[logging.LogRecord] = []
    handler = logging.Handler(logging.WARNING)
    handler.emit = records.append
    # dask's default configuration sets tornado's levels, and tornado.application's own handler
    loggers = [logging.getLogger(name) for name in ("tornado", "tornado.application", "asyncio")]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.WARNING)
        logger.addHandler(handler)
    try:
        yield records
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)
            logger.removeHandler(handler)


@pytest.mark.parametrize(("kind", "ca"), [("plain", "cert"), ("tls", "other")], ids=["plain", "untrusted"])
def test_a_failed_tls_handshake_logs_nothing_and_later_logs_go_through(certs, tornado_warnings, kind, ca):
    with (_server(kind, certs) as port, dask.config.set(_tls_settings(certs, ca)),
          pytest.raises(CurbsideInputError)):
        dask_cluster.check_scheduler(f"tls://127.0.0.1:{port}")
    assert [record.getMessage() for record in tornado_warnings] == []  # it was "SSL Error on ..."
    names = list(dask_cluster._PROBE_LOGGERS)
    for name in names:
        logging.getLogger(name).warning("after the probe")  # a real run's, from this very thread
    assert {record.name for record in tornado_warnings} == set(names)  # (tornado.application's twice)


def test_a_log_from_another_thread_goes_through_during_the_probe(certs, tornado_warnings, monkeypatch):
    """Only the probe's own thread is quiet: a real run's records meanwhile are not dropped."""
    logged = threading.Event()

    def probe_while_another_thread_logs(*args) -> None:
        with dask_cluster._unlogged_in_this_thread(dask_cluster._PROBE_LOGGERS):
            other = threading.Thread(target=lambda: logging.getLogger("tornado.general").warning("a run's"))
            other.start()
            other.join()
            logging.getLogger("tornado.general").warning("the probe's")
            logged.set()

    monkeypatch.setattr(dask_cluster, "_probe_scheduler", probe_while_another_thread_logs)
    dask_cluster.check_scheduler("tcp://127.0.0.1:1")
    assert logged.is_set() and [record.getMessage() for record in tornado_warnings] == ["a run's"]


def _dask_config(folder: Path, settings: dict[str, str]) -> dict[str, str]:
    """The environment of a dask configuration of ``settings`` with dask's documented "version: 1" logging
    configuration (in ``folder``), which leaves tornado's loggers at the root logger's level."""
    folder.mkdir()
    (folder / "curbside-test.yaml").write_text(textwrap.dedent(
        """
        logging:
          version: 1
          disable_existing_loggers: false
          handlers:
            console: {class: logging.StreamHandler, stream: ext://sys.stderr}
          loggers:
            distributed: {level: INFO, handlers: [console], propagate: false}
        """
    ))
    variables = {"DASK_" + key.upper().replace(".", "__").replace("-", "_"): value
                 for key, value in settings.items()}  # distributed.comm.tls.ca-file: DASK_..._TLS__CA_FILE
    return {"DASK_CONFIG": str(folder), **variables}


def _evaluate(tmp_path: Path, address: str, settings: dict[str, str]) -> tuple[int, str]:
    """``localize evaluate --scheduler ADDRESS`` of sessions that do not exist: its exit status, stderr."""
    argv = ["evaluate", str(tmp_path / "no-sessions"), "--maps", str(tmp_path / "no-map.geojson"),
            "--scheduler", address, "-o", str(tmp_path / "report")]
    env = {key: value for key, value in os.environ.items() if not key.startswith("DASK_")}
    env.update(_dask_config(tmp_path / "dask", settings))
    done = subprocess.run([sys.executable, "-c", _LOCALIZE, *argv], capture_output=True, text=True, env=env,
                          cwd=tmp_path, timeout=60)
    return done.returncode, done.stderr


@pytest.mark.parametrize(("kind", "ca", "problem"), [
    ("plain", "cert", "what answers does not speak TLS: a tcp:// scheduler?"),
    ("tls", "other", "its TLS certificate fails verification: self-signed certificate; "),
], ids=["plain", "untrusted"])
def test_the_command_prints_one_line_on_a_failed_tls_handshake(tmp_path, certs, kind, ca, problem):
    """stderr held "WARNING tornado.general: SSL Error on 6 ('127.0.0.1', PORT): [SSL: ...] ..." above it."""
    with _server(kind, certs) as port:
        address = f"tls://127.0.0.1:{port}"
        status, err = _evaluate(tmp_path, address, _tls_settings(certs, ca))
    assert status == 2, err
    assert err.startswith(f"localize: error: --scheduler: cannot reach a dask scheduler at '{address}' "
                          f"({problem}"), err
    assert err.count("\n") == 1, err


def test_a_tls_scheduler_that_answers_is_probed_without_a_word(tmp_path, certs):
    """The probe of a real tls:// scheduler passes silently: the one line is about the sessions."""
    from dask.distributed import LocalCluster
    from distributed.security import Security

    settings = _tls_settings(certs)
    server = {f"{_TLS}.scheduler.cert": str(certs["cert"]), f"{_TLS}.scheduler.key": str(certs["key"])}
    with dask.config.set({**settings, **server}):
        cluster = LocalCluster(n_workers=0, processes=False, protocol="tls://", security=Security(),
                               dashboard_address=":0", scheduler_kwargs={"dashboard": False})
    try:
        status, err = _evaluate(tmp_path, cluster.scheduler_address, settings)
    finally:
        cluster.close()
    assert status == 2, err
    assert err == f"localize: error: {tmp_path / 'no-sessions'}: no such session folder\n", err
