"""The HTTP and WebSocket face of the tracking service (FastAPI; ``docs/service.md`` is the guide).

Every error is a JSON ``{"detail": "one line"}`` with a 4xx status: 400 malformed JSON, 401 missing or
wrong token, 404 unknown session, 409 session ending or still open, 410 session ended, 413 body too
large, 422 rows or configuration refused (nothing changed), 503 too many sessions. The OpenAPI page is
at ``/docs`` (the schema at ``/openapi.json``).
"""

from __future__ import annotations

import json
import logging
import secrets
from contextlib import asynccontextmanager
from typing import Annotated, Any

from fastapi import Depends, FastAPI, Request, WebSocket, WebSocketDisconnect
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from pydantic import ValidationError
from starlette.responses import Response
from starlette.types import ASGIApp, Receive, Scope, Send

from curbside import __version__
from curbside.localize.live import IMU_COLUMNS
from curbside.localize.serve.models import (
    ErrorMessage,
    Estimate,
    Health,
    NewSession,
    Samples,
    SessionCreated,
    TrackInfo,
    TrackSummary,
)
from curbside.localize.serve.service import ServiceConfig, ServiceError, TrackingService
from curbside.localize.serve.store import TRACK_FILES

logger = logging.getLogger(__name__)

#: Largest request body (and WebSocket message) accepted, bytes: ~30,000 IMU rows of JSON.
MAX_BODY_BYTES = 4 * 2**20

_ERRORS = {status: {"model": ErrorMessage} for status in (400, 401, 404, 409, 410, 413, 422, 503)}


class BodyLimit:
    """ASGI middleware: 413 for a body over ``max_bytes`` (by ``Content-Length`` or as it streams in)."""

    def __init__(self, app: ASGIApp, max_bytes: int = MAX_BODY_BYTES) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        length = dict(scope["headers"]).get(b"content-length")
        if length is not None and length.isdigit() and int(length) > self.max_bytes:
            await _too_large(self.max_bytes)(scope, receive, send)
            return
        seen = 0

        async def counted() -> dict:
            nonlocal seen
            message = await receive()
            seen += len(message.get("body", b""))
            if seen > self.max_bytes:
                raise _BodyTooLargeError
            return message

        try:
            await self.app(scope, counted, send)
        except _BodyTooLargeError:
            await _too_large(self.max_bytes)(scope, receive, send)


class _BodyTooLargeError(Exception):
    pass


def _too_large(max_bytes: int) -> Response:
    return JSONResponse(
        {"detail": f"request body over {max_bytes} bytes: send fewer rows per request"}, status_code=413
    )


def _one_line(errors: list[dict[str, Any]]) -> tuple[int, str]:
    """Status and one-line reason of pydantic errors (the first one, and how many more)."""
    first = errors[0]
    if first.get("type") == "json_invalid":
        return 400, f"malformed JSON ({first.get('ctx', {}).get('error', first.get('msg'))})"
    loc = [str(p) for p in first.get("loc", ()) if p != "body"]
    where = ""
    for part in loc:
        where += f"[{part}]" if part.isdigit() else f".{part}" if where else part
    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
    return 422, f"{where or 'body'}: {first.get('msg', 'invalid')}{more}"


_BEARER = HTTPBearer(auto_error=False, description="the service's token (localize serve --token-file)")


def _authorised(token: str | None, credentials: HTTPAuthorizationCredentials | None) -> bool:
    return token is None or (
        credentials is not None and secrets.compare_digest(credentials.credentials.encode(), token.encode())
    )


async def require_token(
    request: Request, credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_BEARER)]
) -> None:
    """Dependency of every route but ``/health``: 401 unless the service's token is given."""
    if not _authorised(request.app.state.token, credentials):
        raise ServiceError(401, "missing or wrong bearer token")


def create_app(config: ServiceConfig, service: TrackingService | None = None) -> FastAPI:
    """The FastAPI application of a :class:`TrackingService` (made from ``config`` unless given)."""
    service = service or TrackingService(config)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        await service.start()
        try:
            yield
        finally:
            await service.stop()

    app = FastAPI(
        title="curbside live tracking",
        version=__version__,
        summary="Stream a walker's phone IMU and GNSS in; get which side of which street back.",
        description="See docs/service.md. Rows use the SPEC's imu.csv and gnss.csv column names and units.",
        lifespan=lifespan,
        responses=_ERRORS,
    )
    app.state.service = service
    app.state.token = config.token
    app.add_middleware(BodyLimit, max_bytes=MAX_BODY_BYTES)
    auth = [Depends(require_token)]

    @app.exception_handler(ServiceError)
    async def _service_error(request: Request, exc: ServiceError) -> JSONResponse:
        headers = {"WWW-Authenticate": "Bearer"} if exc.status == 401 else None
        return JSONResponse({"detail": exc.detail}, status_code=exc.status, headers=headers)

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        status, detail = _one_line(list(exc.errors()))
        return JSONResponse({"detail": detail}, status_code=status)

    @app.get("/health", response_model=Health, tags=["service"])
    async def health() -> dict[str, Any]:
        """Liveness and what the service tracks on (no token needed)."""
        return {
            "status": "ok",
            "version": __version__,
            "sessions": len(service.sessions),
            "map": config.map_path,
            "sidewalk_segments": len(service.places),
        }

    _add_session_routes(app, service, config, auth)
    _add_track_routes(app, service, auth)
    return app


def _add_session_routes(app: FastAPI, service: TrackingService, config: ServiceConfig, auth: list) -> None:
    """``/sessions``: open, feed (HTTP or WebSocket), read and end a walker's session."""

    @app.post(
        "/sessions", status_code=201, response_model=SessionCreated, dependencies=auth, tags=["sessions"]
    )
    async def create_session(body: NewSession) -> dict[str, Any]:
        """Open a session. Keep the returned ``id`` secret: it is the only key to the session."""
        start = None if body.start is None else body.start.model_dump()
        entry = await service.create(start, body.config)
        return {
            "id": entry.id,
            "config": entry.live.config.to_dict(),
            "fix_delay_s": config.limits.fix_delay_s,
            "idle_timeout_s": config.idle_timeout_s,
        }

    @app.post("/sessions/{session_id}/samples", response_model=Estimate, dependencies=auth, tags=["sessions"])
    async def push_samples(session_id: str, body: Samples) -> dict[str, Any]:
        """Feed rows (each stream in time order); returns the latest estimate. A refused batch changes
        nothing."""
        return await _push(service, session_id, body)

    @app.get("/sessions/{session_id}/estimate", response_model=Estimate, dependencies=auth, tags=["sessions"])
    async def get_estimate(session_id: str) -> dict[str, Any]:
        """The latest estimate."""
        return service.estimate(session_id)

    @app.delete("/sessions/{session_id}", response_model=TrackSummary, dependencies=auth, tags=["sessions"])
    async def end_session(session_id: str) -> dict[str, Any]:
        """End the session: the filter finishes and the whole track is saved (``GET /tracks/{id}``)."""
        return await service.end(session_id, "deleted")

    @app.websocket("/sessions/{session_id}/stream")
    async def stream(websocket: WebSocket, session_id: str) -> None:
        """Messages are ``POST .../samples`` bodies (``"end": true`` ends the session); each gets the
        estimate, the error ``{"detail", "status"}``, or, after ``end``, the track summary."""
        await _serve_stream(websocket, session_id, service)


def _add_track_routes(app: FastAPI, service: TrackingService, auth: list) -> None:
    """``/tracks``: the saved tracks of ended sessions."""

    @app.get("/tracks", response_model=list[TrackInfo], dependencies=auth, tags=["tracks"])
    async def list_tracks() -> list[dict[str, Any]]:
        """Every saved track, by key (a hash of its session id: reading one needs the id)."""
        return service.store.list()

    @app.get("/tracks/{session_id}", dependencies=auth, tags=["tracks"])
    async def get_track(session_id: str) -> dict[str, Any]:
        """An ended session's ``run.json`` and its track as GeoJSON."""
        folder = service.track_folder(session_id)
        return {
            "run": json.loads((folder / "run.json").read_text(encoding="utf-8")),
            "track": json.loads((folder / "track.geojson").read_text(encoding="utf-8")),
        }

    @app.get("/tracks/{session_id}/{name}", dependencies=auth, tags=["tracks"])
    async def get_track_file(session_id: str, name: str) -> FileResponse:
        """One file of an ended session's track: ``track.csv``, ``track.geojson`` or ``run.json``."""
        if name not in TRACK_FILES:
            raise ServiceError(404, f"no such file; one of {', '.join(TRACK_FILES)}")
        return FileResponse(service.track_folder(session_id) / name)


async def _push(service: TrackingService, session_id: str, body: Samples) -> dict[str, Any]:
    imu, columns = body.imu_array() if body.imu else (None, IMU_COLUMNS)
    gnss = body.gnss_array() if body.gnss else None
    return await service.push(session_id, imu, columns, gnss)


def _ws_credentials(websocket: WebSocket) -> HTTPAuthorizationCredentials | None:
    header = websocket.headers.get("authorization", "")
    scheme, _, token = header.partition(" ")
    if scheme.lower() == "bearer" and token:
        return HTTPAuthorizationCredentials(scheme="Bearer", credentials=token)
    token = websocket.query_params.get("access_token")
    return HTTPAuthorizationCredentials(scheme="Bearer", credentials=token) if token else None


async def _serve_stream(websocket: WebSocket, session_id: str, service: TrackingService) -> None:
    """The WebSocket loop: one JSON answer per message; a bad message does not close the connection."""
    refusal = None
    if not _authorised(websocket.app.state.token, _ws_credentials(websocket)):
        refusal = ServiceError(401, "missing or wrong bearer token")
    else:
        try:
            service.entry(session_id)
        except ServiceError as exc:
            refusal = exc
    if refusal is not None:
        await websocket.send_denial_response(JSONResponse({"detail": refusal.detail}, refusal.status))
        return
    await websocket.accept()
    try:
        while True:
            text = await websocket.receive_text()
            try:
                body = Samples.model_validate_json(text)
                answer = await _push(service, session_id, body) if body.imu or body.gnss else None
                if body.end:
                    answer = await service.end(session_id, "deleted")
                elif answer is None:
                    answer = service.estimate(session_id)
            except ValidationError as exc:
                status, detail = _one_line(exc.errors())
                answer = {"detail": detail, "status": status}
            except ServiceError as exc:
                answer = {"detail": exc.detail, "status": exc.status}
            await websocket.send_json(answer)
            if "saved" in answer:  # the track summary: the session has ended
                await websocket.close()
                return
    except WebSocketDisconnect:
        return
