"""Shared pytest fixtures."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
TEST_DATA = Path(__file__).resolve().parent / "data"

# A test run started in the background of a non-interactive shell (`make test &`, nohup) inherits SIGINT
# ignored, and so would every command the Ctrl-C tests start: they would never see their Ctrl-C. A
# handler is reset to the default in a child, where an ignored signal stays ignored.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def shared_data() -> Path:
    """``../shared/data`` beside the checkout; skips the test when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not beside this checkout")
    return SHARED_DATA


@pytest.fixture
def cache_in_tmp(tmp_path, monkeypatch) -> Path:
    """curbside's cache (rasters, Overpass answers) in ``tmp_path / "cache"`` for the test."""
    cache = tmp_path / "cache"
    monkeypatch.setattr("curbside.settings.cache_dir", cache)
    return cache


@pytest.fixture
def test_data() -> Path:
    """The small in-repo fixtures in ``tests/data``."""
    return TEST_DATA


@pytest.fixture(scope="module")
def ipin_walk():
    """A real IPIN 2023 walk (``serve_fixtures.TRIAL``): 32 s of 50 Hz IMU with the quaternion, 1 Hz
    GNSS, a start pose."""
    from serve_fixtures import TRIAL

    from curbside.localize.readers import read_any

    return read_any(TRIAL)


@pytest.fixture(scope="module")
def ronin_model():
    """The bundled RoNIN model."""
    from curbside.localize.ronin.infer import load_model

    return load_model()


@pytest.fixture(scope="module")
def walk_result(ipin_walk, ronin_model):
    """:func:`ipin_walk`'s track, as a session of the service would leave it."""
    from curbside.localize.live import stream_session
    from curbside.localize.runconfig import RunConfig

    return stream_session(ipin_walk, None, RunConfig.for_mode("fused"), ronin_model)
