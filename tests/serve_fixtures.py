"""What the live-service tests share: the real IPIN walk they stream and a test client of the app."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import uvicorn
from fastapi.testclient import TestClient

from curbside.localize.serve.app import create_app
from curbside.localize.serve.service import ServiceConfig, TrackingService

#: A real IPIN 2023 walk: 32 s of 50 Hz IMU with the quaternion, 1 Hz GNSS, a start pose.
TRIAL = f"{Path(__file__).parent / 'data' / 'sessions' / 'ipin2023-cut.h5'}::TrainingTrial01_repetition01"


def client_for(tmp_path: Path, model, **kwargs) -> TestClient:
    """A test client of a service writing under ``tmp_path / "data"`` (``kwargs``: ``ServiceConfig``)."""
    config = ServiceConfig(data_dir=tmp_path / "data", **kwargs)
    return TestClient(create_app(config, TrackingService(config, model)))


def bare_client(tmp_path: Path, token: str) -> TestClient:
    """The app with ``token``, without its lifespan (the schema and the pages need no session)."""
    return TestClient(create_app(ServiceConfig(data_dir=tmp_path / "data", token=token)))


@contextlib.contextmanager
def live_service(tmp_path: Path, model, log_level: str = "warning") -> Iterator[tuple[str, uvicorn.Server]]:
    """A service writing under ``tmp_path / "data"``, served by uvicorn on a free loopback port in a
    thread: its base URL and server (stopped on exit). uvicorn leaves logging alone (``log_config=None``)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    config = ServiceConfig(data_dir=tmp_path / "data")
    app = create_app(config, TrackingService(config, model))
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_config=None,
                                           log_level=log_level))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 60.0
        while not server.started:
            assert time.monotonic() < deadline and thread.is_alive(), "uvicorn did not start"
            time.sleep(0.05)
        yield f"http://127.0.0.1:{port}", server
    finally:
        server.should_exit = True
        thread.join(30)
