"""The HTTP and WebSocket face of the tracking service (FastAPI; ``docs/service.md`` is the guide).

Every error is a JSON ``{"detail": "one line"}`` with a 4xx status: 400 malformed JSON, 401 missing or
wrong token, 404 unknown session or track, 409 session ending or still open (or a track folder the
service did not write), 410 session ended, 413 body too large, 415 a body that is not sent as JSON,
422 rows or configuration refused (nothing changed, unless the IMU stream proved unusable:
:mod:`~curbside.localize.serve.intake`), 503 too many sessions or the service stopping; a bug is a
500 naming only the exception's type. The API reference is at ``/docs`` (a page that needs nothing
from outside; Swagger UI, from a CDN, at ``/docs/swagger``; the schema at ``/openapi.json``; all
public: they hold no data).
"""

from __future__ import annotations

import json
import logging
import re
import secrets
from contextlib import asynccontextmanager
from contextvars import ContextVar
from typing import Annotated, Any

from fastapi import Depends, FastAPI, Request, WebSocket, WebSocketDisconnect
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, JSONResponse
from fastapi.routing import APIRoute, APIWebSocketRoute
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from pydantic import BaseModel, Field, ValidationError
from starlette.responses import Response
from starlette.types import ASGIApp, Receive, Scope, Send

from curbside import __version__
from curbside.io import json_ready
from curbside.localize.live import IMU_COLUMNS
from curbside.localize.serve.apidocs import STREAM, WebSocketDoc, api_reference_html, swagger_ui_html
from curbside.localize.serve.common import session_label
from curbside.localize.serve.download import OpenFileResponse
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

#: ``Content-Type`` of each file ``GET /tracks/{id}/{name}`` serves.
_MEDIA_TYPES = {
    "track.csv": "text/csv", "track.geojson": "application/geo+json", "run.json": "application/json"
}

#: The bodies ``GET /tracks/{id}/{name}`` may send, for the OpenAPI schema.
_FILE_BODIES = {media: {"schema": {"type": "string", "format": "binary"}} for media in _MEDIA_TYPES.values()}

#: Error answers routes share (each route declares its own set: :func:`_errors`): the token's, a bug's,
#: a JSON body's, an unknown or ended session's, a missing track's.
_TOKEN = {401: "missing or wrong bearer token (when the service has one)"}
_BUG = {500: "a bug of the service (the detail names only the exception's type; see the service log)"}
_BODY = {
    400: "malformed JSON",
    413: "a body over 4 MiB: send fewer rows per request",
    415: "the body is not sent as application/json",
}
_NO_SESSION = {
    404: "no such session (or one whose filter never started: it left no track)",
    410: "the session has ended; its track is at /tracks/{id}",
}
_NO_TRACK = {
    404: "no such track: never saved, removed, or not this session's id (a track is read by its "
    "session's id, not by its key)",
    409: "the session is still open: DELETE /sessions/{id} finishes its track",
}

#: The WebSocket routes' entries on the API reference page, which OpenAPI has no place for.
_WEBSOCKET_DOCS: dict[str, WebSocketDoc] = {STREAM.path: STREAM}


def _errors(own: dict[int, str], token: bool = True, body: bool = True) -> dict[int | str, dict[str, Any]]:
    """A route's error answers for the OpenAPI schema: its ``own`` (status: when), the token's 401 when
    it needs the ``token``, and a bug's 500; ``body``: each with its ``ErrorMessage`` (not for HEAD)."""
    statuses = {**(_TOKEN if token else {}), **own, **_BUG}
    return {status: {"description": when, **({"model": ErrorMessage} if body else {})}
            for status, when in sorted(statuses.items())}


class TrackRecord(BaseModel):
    """``GET /tracks/{id}``: an ended session's ``run.json`` and its track."""

    run: dict[str, Any] = Field(
        description="the track's run.json: the whole run configuration, the session's record (service: "
        "map, created, ended, reason, start, failed) and what the filter did"
    )
    track: dict[str, Any] = Field(
        description="track.geojson: a GeoJSON FeatureCollection, a Point per filter update with the "
        "columns of track.csv as properties"
    )


class BodyLimit:
    """ASGI middleware: 413 for a body over ``max_bytes`` (by ``Content-Length`` or as it streams in).

    The body is read whole before the route runs (the routes parse it whole anyway): a limit raised
    while the route reads it would reach FastAPI's body parser, which turns any error into a 400.
    """

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
        chunks, seen = [], 0
        while True:
            message = await receive()
            if message["type"] != "http.request":  # the client went away
                return
            chunks.append(message.get("body", b""))
            seen += len(chunks[-1])
            if seen > self.max_bytes:
                await _too_large(self.max_bytes)(scope, receive, send)
                return
            if not message.get("more_body", False):
                break
        body: dict | None = {"type": "http.request", "body": b"".join(chunks), "more_body": False}

        async def replay() -> dict:
            nonlocal body
            if body is None:
                return await receive()  # the disconnect, for a route that waits for it
            message, body = body, None
            return message

        await self.app(scope, replay, send)


def _too_large(max_bytes: int) -> Response:
    return JSONResponse(
        {"detail": f"request body over {max_bytes} bytes: send fewer rows per request"}, status_code=413
    )


class _DeniedHandshakeFilter(logging.Filter):
    """Drops uvicorn's "ASGI callable returned without completing handshake." after a WebSocket this
    app refused with an HTTP response: its websockets-sansio protocol does not count a denial response
    as a completed handshake (uvicorn PR 3138) and logs an error for every refusal. ``_denied`` is set
    in the connection's task, whose context the log call shares, so every other case is still logged.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        return not (_denied.get() and record.getMessage().startswith("ASGI callable returned without"))


_denied: ContextVar[bool] = ContextVar("curbside_ws_denied", default=False)


class _SessionIdFilter(logging.Filter):
    """Keeps session ids and tokens out of uvicorn's WebSocket lines (``localize -v serve``:
    ``127.0.0.1:50132 - "WebSocket /sessions/ID/stream?access_token=TOKEN" [accepted]``): the id is
    the key to a session, so the path names the session by its label (:func:`session_label`), and the
    query string, which may hold the token, is left out."""

    def filter(self, record: logging.LogRecord) -> bool:
        args = record.args
        if isinstance(args, tuple) and len(args) >= 2 and str(record.msg).startswith('%s - "WebSocket %s"'):
            record.args = (args[0], _without_secrets(str(args[1])), *args[2:])
        return True


def _without_secrets(path: str) -> str:
    """A request path with its session id replaced by the session's label and no query string."""
    path = path.partition("?")[0]
    return re.sub(r"(?<=/sessions/)[^/]+", lambda m: f"<{session_label(m.group())}>", path)


def _guard_uvicorn_log() -> None:
    uvicorn_log = logging.getLogger("uvicorn.error")
    for kind in (_DeniedHandshakeFilter, _SessionIdFilter):
        if not any(isinstance(f, kind) for f in uvicorn_log.filters):
            uvicorn_log.addFilter(kind())


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


async def require_json(request: Request) -> None:
    """Dependency of the routes with a JSON body: 415 for a body sent as another media type (or none),
    which FastAPI would otherwise validate as bytes ("Input should be a valid dictionary")."""
    media = request.headers.get("content-type", "").partition(";")[0].strip().lower()
    json_media = media == "application/json" or (media.startswith("application/") and media.endswith("+json"))
    if not json_media and await request.body():
        sent = media or "no Content-Type"
        raise ServiceError(415, f"the body must be JSON, sent as Content-Type: application/json (not {sent})")


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
        docs_url=None,  # Swagger UI loads from a CDN: /docs is the offline page of _add_docs_routes
        redoc_url=None,
    )
    app.state.service = service
    app.state.token = config.token
    _guard_uvicorn_log()
    app.add_middleware(BodyLimit, max_bytes=MAX_BODY_BYTES)
    auth = [Depends(require_token)]

    @app.exception_handler(ServiceError)
    async def _service_error(request: Request, exc: ServiceError) -> JSONResponse:
        headers = {"WWW-Authenticate": "Bearer"} if exc.status == 401 else None
        return JSONResponse({"detail": exc.detail}, status_code=exc.status, headers=headers)

    @app.exception_handler(Exception)
    async def _bug(request: Request, exc: Exception) -> JSONResponse:
        # Starlette still re-raises it after this reply, so the traceback goes to the log, not the client
        detail = f"internal error ({type(exc).__name__}); see the service log"
        return JSONResponse({"detail": detail}, status_code=500)

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        status, detail = _one_line(list(exc.errors()))
        return JSONResponse({"detail": detail}, status_code=status)

    @app.get("/health", response_model=Health, tags=["service"], responses=_errors({}, token=False))
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
    _add_head_routes(app)
    _add_docs_routes(app)
    return app


def _add_head_routes(app: FastAPI) -> None:
    """``HEAD`` on each ``GET`` route of the schema that has none (FastAPI adds none): the ``GET``'s
    endpoint, token and errors, so the same status and headers (``Content-Length`` included); the
    server leaves out the body. Each is a short operation of its own, its answers without a body."""
    routes = [r for r in app.routes if isinstance(r, APIRoute) and r.include_in_schema]
    has_head = {r.path for r in routes if "HEAD" in r.methods}
    for get in [r for r in routes if "GET" in r.methods and r.path not in has_head]:
        errors = {s: {"description": a["description"]} for s, a in get.responses.items() if str(s)[0] in "45"}
        app.add_api_route(
            get.path, get.endpoint, methods=["HEAD"], name="head_" + get.name.removeprefix("get_"),
            response_model=get.response_model, status_code=get.status_code, dependencies=get.dependencies,
            tags=get.tags, response_class=get.response_class,
            description=f"The headers ``GET {get.path}`` would send (its status, ``Content-Type`` and "
            "``Content-Length``), without the body.",
            responses={get.status_code or 200: {"description": "the headers of the GET's answer, no body"},
                       **errors},
        )


def _add_docs_routes(app: FastAPI) -> None:
    """``/docs``: the API reference as one page that needs nothing from outside; ``/docs/swagger``:
    Swagger UI, which the browser loads from the jsDelivr CDN (offline, a line that links to ``/docs``).
    The schema leaves out the answers FastAPI adds by itself (422 for a path parameter): every route
    declares its own; and a ``HEAD``'s answers have no body."""
    page: list[str] = []  # drawn at the first request, once every route is in the schema
    openapi = app.openapi

    def schema() -> dict[str, Any]:
        if app.openapi_schema is None:
            for item in openapi()["paths"].values():
                for method, op in item.items():
                    answer = op["responses"].get("422", {}).get("content", {}).get("application/json", {})
                    if answer.get("schema", {}).get("$ref", "").endswith("/HTTPValidationError"):
                        del op["responses"]["422"]
                    if method == "head":  # no body: not the GET's, nor an error's
                        for answer in op["responses"].values():
                            answer.pop("content", None)
            for name in ("HTTPValidationError", "ValidationError"):
                app.openapi_schema.get("components", {}).get("schemas", {}).pop(name, None)
        return app.openapi_schema

    app.openapi = schema

    @app.api_route("/docs", methods=["GET", "HEAD"], include_in_schema=False)
    async def reference() -> HTMLResponse:
        if not page:
            websockets = [_WEBSOCKET_DOCS[r.path] for r in app.routes if isinstance(r, APIWebSocketRoute)]
            page.append(api_reference_html(app.openapi(), websockets=websockets))
        return HTMLResponse(page[0])

    @app.api_route("/docs/swagger", methods=["GET", "HEAD"], include_in_schema=False)
    async def swagger() -> HTMLResponse:
        return HTMLResponse(swagger_ui_html(app.openapi_url, f"{app.title}: Swagger UI"))


def _add_session_routes(app: FastAPI, service: TrackingService, config: ServiceConfig, auth: list) -> None:
    """``/sessions``: open, feed (HTTP or WebSocket), read and end a walker's session."""

    json_body = [*auth, Depends(require_json)]

    @app.post(
        "/sessions",
        status_code=201,
        response_model=SessionCreated,
        dependencies=json_body,
        tags=["sessions"],
        responses=_errors({**_BODY, 422: "a start pose or configuration refused",
                           503: "the service holds its maximum of sessions (--max-sessions)"}),
    )
    async def create_session(body: NewSession | None = None) -> dict[str, Any]:
        """Open a session (no body: no start pose, the service's configuration). Keep the returned ``id``
        secret: it is the only key to the session."""
        body = body or NewSession()
        start = None if body.start is None else body.start.model_dump()
        entry = await service.create(start, body.config or {})
        return {
            "id": entry.id,
            "config": entry.live.config.to_dict(),
            "fix_delay_s": config.limits.fix_delay_s,
            "idle_timeout_s": config.idle_timeout_s,
        }

    @app.post("/sessions/{session_id}/samples", response_model=Estimate, dependencies=json_body,
              tags=["sessions"], responses=_errors({
                  **_BODY, **_NO_SESSION, 409: "the session is ending",
                  422: "rows or values refused (nothing changed), ``end`` over HTTP, or the IMU stream "
                  "proved unusable (the session fails)",
                  503: "the service stopped before it could answer"}))
    async def push_samples(session_id: str, body: Samples) -> dict[str, Any]:
        """Feed rows (each stream in time order); returns the latest estimate. A refused batch changes
        nothing, but for the one that shows the IMU stream unusable: then the session fails."""
        if body.end:
            raise ServiceError(
                422, "end is for the WebSocket; end an HTTP session with DELETE /sessions/{id}"
            )
        return await _push(service, session_id, body)

    @app.get("/sessions/{session_id}/estimate", response_model=Estimate, dependencies=auth, tags=["sessions"],
             responses=_errors(_NO_SESSION))
    async def get_estimate(session_id: str) -> dict[str, Any]:
        """The latest estimate."""
        return service.estimate(session_id)

    @app.delete("/sessions/{session_id}", response_model=TrackSummary, dependencies=auth, tags=["sessions"],
                responses=_errors({
                    **_NO_SESSION, 409: "the session is ending",
                    422: "finishing failed on the session's input: it has ended with its track so far",
                    503: "the service stopped before it could answer"}))
    async def end_session(session_id: str) -> dict[str, Any]:
        """End the session: the filter finishes and the whole track is saved, read with the session's
        id (``GET /tracks/{id}``); a session whose filter never started saves none (``saved``)."""
        return await service.end(session_id, "deleted")

    @app.websocket("/sessions/{session_id}/stream")
    async def stream(websocket: WebSocket, session_id: str) -> None:
        """Messages are ``POST .../samples`` bodies (``"end": true`` ends the session); each gets the
        estimate, the error ``{"detail", "status"}``, or, after ``end``, the track summary."""
        await _serve_stream(websocket, session_id, service)


def _add_track_routes(app: FastAPI, service: TrackingService, auth: list) -> None:
    """``/tracks``: the saved tracks of ended sessions; read or remove one."""

    @app.get("/tracks", response_model=list[TrackInfo], dependencies=auth, tags=["tracks"],
             responses=_errors({}))
    async def list_tracks() -> list[dict[str, Any]]:
        """Every saved track, by key (a hash of its session id: reading one needs the id)."""
        return service.store.list()

    @app.get("/tracks/{session_id}", dependencies=auth, tags=["tracks"],
             responses={200: {"model": TrackRecord, "description": "its run.json and GeoJSON"},
                        **_errors(_NO_TRACK)})
    def get_track(session_id: str) -> Response:
        """An ended session's ``run.json`` and its track as GeoJSON: ``{"run": ..., "track": ...}``."""
        # Off the event loop (a route without async), and the GeoJSON as it is on disk: parsing and
        # encoding an hour's track again took 0.4 s.
        folder = service.track_folder(session_id)
        try:
            run = json_ready(json.loads((folder / "run.json").read_text(encoding="utf-8")))
            track = (folder / "track.geojson").read_bytes()
        except FileNotFoundError:  # deleted meanwhile
            raise ServiceError(404, "no such track") from None
        body = b'{"run": ' + json.dumps(run, allow_nan=False).encode() + b', "track": ' + track + b"}"
        return Response(body, media_type="application/json")

    @app.get("/tracks/{session_id}/{name}", dependencies=auth, tags=["tracks"], response_class=Response,
             responses=_file_responses(head=False))
    def get_track_file(session_id: str, name: str) -> OpenFileResponse:
        """One file of an ended session's track: ``track.csv``, ``track.geojson`` or ``run.json``.
        ``Range: bytes=A-B`` (``A-``, ``-N``) gets a 206 with those bytes, several ranges (at most 16)
        a 206 ``multipart/byteranges``. A download that has started is sent whole even if the track is
        deleted."""
        return _track_file(service, session_id, name)

    @app.head("/tracks/{session_id}/{name}", dependencies=auth, tags=["tracks"], response_class=Response,
              responses=_file_responses(head=True))
    def head_track_file(session_id: str, name: str) -> OpenFileResponse:
        """The headers ``GET`` would send for the file and the same ``Range``, without the body: its size
        (``Content-Length``), ``ETag``, ``Last-Modified`` and ``Accept-Ranges``."""
        return _track_file(service, session_id, name)

    @app.delete("/tracks/{session_id}", response_model=TrackInfo, dependencies=auth, tags=["tracks"],
                responses=_errors({**_NO_TRACK, 409: "the session is still open, or the folder was not "
                                   "written by the service (it is left alone)"}))
    async def delete_track(session_id: str) -> dict[str, Any]:
        """Remove an ended session's track (its listing entry is the reply). Only a folder the service
        wrote is removed, and in it only the files it wrote; 409 while the session is open."""
        return await service.delete_track(session_id)


def _file_responses(head: bool) -> dict[int | str, dict[str, Any]]:
    """The answers of ``GET`` (``head``: ``HEAD``) ``/tracks/{id}/{name}`` for the OpenAPI schema."""
    only = ": its headers, no body" if head else ""
    answers = {
        200: ("the whole file (no Range, or one not served: see docs/service.md)", _FILE_BODIES),
        206: ("the range asked for (Content-Range says which); several ranges as multipart/byteranges",
              {**_FILE_BODIES, "multipart/byteranges": {"schema": {"type": "string", "format": "binary"}}}),
        416: ("no range asked for starts before the end of the file (Content-Range: bytes */SIZE)", {}),
    }
    files = {status: {"description": what + only, **({} if head or not bodies else {"content": bodies})}
             for status, (what, bodies) in answers.items()}
    missing = {**_NO_TRACK, 404: f"{_NO_TRACK[404]}; or no such file (one of {', '.join(TRACK_FILES)})"}
    return {**files, **_errors(missing, body=not head)}


def _track_file(service: TrackingService, session_id: str, name: str) -> OpenFileResponse:
    """The reply to ``GET`` or ``HEAD /tracks/{session_id}/{name}``, its file already open."""
    if name not in TRACK_FILES:
        raise ServiceError(404, f"no such file; one of {', '.join(TRACK_FILES)}")
    try:  # opened here, not once the route has returned: see OpenFileResponse
        file = (service.track_folder(session_id) / name).open("rb")
    except FileNotFoundError:  # deleted since it was found
        raise ServiceError(404, "no such track (deleted)") from None
    return OpenFileResponse(file, _MEDIA_TYPES[name])


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
        _denied.set(True)
        return
    await websocket.accept()
    try:
        while True:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                return
            # a binary frame holding UTF-8 JSON is the same message as a text frame
            data = message["text"] if message.get("text") is not None else message.get("bytes") or b""
            body, answer = await _answer(service, session_id, data)
            await websocket.send_json(answer)
            if body is not None and body.end and session_id not in service.sessions:  # it has ended
                await websocket.close()
                return
    except WebSocketDisconnect:
        return


async def _answer(
    service: TrackingService, session_id: str, data: str | bytes
) -> tuple[Samples | None, dict[str, Any]]:
    """A WebSocket message's batch (``None`` if it is not one) and its answer: the estimate, the track
    summary after ``end``, or the error ``{"detail", "status"}``."""
    body = None
    try:
        body = Samples.model_validate_json(data)
        answer = await _push(service, session_id, body) if body.imu or body.gnss else None
        if body.end:
            answer = await service.end(session_id, "ended")
        elif answer is None:
            answer = service.estimate(session_id)
    except ValidationError as exc:
        status, detail = _one_line(exc.errors())
        answer = {"detail": detail, "status": status}
    except ServiceError as exc:
        answer = {"detail": exc.detail, "status": exc.status}
    return body, answer
