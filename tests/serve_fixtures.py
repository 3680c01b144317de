"""What the live-service tests share: the real IPIN walk they stream and a test client of the app."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient

from curbside.localize.serve.app import create_app
from curbside.localize.serve.service import ServiceConfig, TrackingService

#: A real IPIN 2023 walk: 32 s of 50 Hz IMU with the quaternion, 1 Hz GNSS, a start pose.
TRIAL = f"{Path(__file__).parent / 'data' / 'sessions' / 'ipin2023-cut.h5'}::TrainingTrial01_repetition01"


def client_for(tmp_path: Path, model, **kwargs) -> TestClient:
    """A test client of a service writing under ``tmp_path / "data"`` (``kwargs``: ``ServiceConfig``)."""
    config = ServiceConfig(data_dir=tmp_path / "data", **kwargs)
    return TestClient(create_app(config, TrackingService(config, model)))
