"""The service's API reference as one self-contained HTML page, drawn from its OpenAPI schema.

FastAPI's own ``/docs`` page is Swagger UI, which the browser loads from a CDN: offline, or on a
network that blocks it, the page is blank. This page needs nothing but itself (no script, no outside
style or font), so it reads wherever the service runs. The interactive Swagger UI stays at
``/docs/swagger`` for those who can load it (:func:`swagger_ui_html`: offline, it says so and links
back here). OpenAPI has no place for a WebSocket route: :data:`STREAM` describes the session stream,
and the page draws it with the schema's routes.
"""

from __future__ import annotations

import html
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

_METHODS = ("get", "head", "post", "put", "patch", "delete")

#: Where Swagger UI's script and style come from (FastAPI's defaults).
SWAGGER_JS_URL = "https://cdn.jsdelivr.net/npm/swagger-ui-dist@5/swagger-ui-bundle.js"
SWAGGER_CSS_URL = "https://cdn.jsdelivr.net/npm/swagger-ui-dist@5/swagger-ui.css"

_STYLE = """
body{font:15px/1.45 system-ui,sans-serif;margin:0 auto;max-width:60rem;padding:1rem;color:#222}
h1{font-size:1.5rem;margin-bottom:.2rem}h2{margin-top:2rem;border-bottom:1px solid #ccc}
h3{font-size:1.05rem;margin:1.4rem 0 .3rem;font-family:ui-monospace,monospace;word-break:break-all}
.m{display:inline-block;min-width:4.2em;padding:0 .4em;border-radius:3px;color:#fff;text-align:center}
.get{background:#1f6feb}.head{background:#0a7ea4}.post{background:#2da44e}.put,.patch{background:#bf8700}
.delete{background:#cf222e}.ws{background:#6e40c9}
.tok{font:600 .75rem system-ui,sans-serif;color:#8250df;border:1px solid #8250df;border-radius:3px;
padding:0 .3em}
.scroll{overflow-x:auto}table{border-collapse:collapse;margin:.3rem 0 .8rem}
td,th{border:1px solid #ddd;padding:.2rem .5rem;text-align:left;vertical-align:top}
th{background:#f6f8fa}code{font-family:ui-monospace,monospace;font-size:.92em}
p.d{white-space:pre-wrap;margin:.3rem 0}
"""


@dataclass(frozen=True)
class WebSocketDoc:
    """What the reference page says of a WebSocket route, which an OpenAPI schema cannot hold.

    Attributes
    ----------
    path, summary, description
        The route and what it does (``double backticks`` render as code).
    parameters
        ``(name, in, required, description)`` of each parameter.
    messages
        ``(direction, schema, description)`` of each kind of message: ``in`` or ``out``, a component
        schema's name (``""``: none), and when it is sent.
    refusals
        ``(HTTP status, when)`` of each refusal of the handshake.
    errors
        ``(status, when)`` of each error message, which leaves the connection open.
    close_codes
        ``(code, when)`` of each way the connection closes.
    token
        Whether the route needs the service's token.
    """

    path: str
    summary: str
    description: str
    parameters: tuple[tuple[str, str, str, str], ...]
    messages: tuple[tuple[str, str, str], ...]
    refusals: tuple[tuple[str, str], ...]
    errors: tuple[tuple[str, str], ...]
    close_codes: tuple[tuple[str, str], ...]
    token: bool = True


#: ``/sessions/{session_id}/stream`` (``curbside.localize.serve.app``).
STREAM = WebSocketDoc(
    path="/sessions/{session_id}/stream",
    summary="Stream",
    description="A session over one WebSocket: each message is a batch of rows (a ``POST .../samples`` "
    "body, as a text frame or a binary frame of UTF-8 JSON) and gets one answer on the same connection, "
    "in order. ``\"end\": true`` in the last batch ends the session (as ``DELETE /sessions/{id}``, with "
    "the reason ``ended``) and its answer is the track summary. A refused message changes nothing and "
    "the connection stays open. Several connections to one session are all served; their rows must "
    "still go forward in time together.",
    parameters=(
        ("session_id", "path", "yes", "the session's id (POST /sessions)"),
        ("Authorization", "header", "no", "``Bearer TOKEN``, when the service has a token"),
        ("access_token", "query", "no", "the token, for a browser, which cannot set headers on a "
         "WebSocket (use TLS: a query string shows in proxies' logs)"),
    ),
    messages=(
        ("in", "Samples", "every message: ``imu`` and ``gnss`` rows; ``\"end\": true`` in the last"),
        ("out", "Estimate", "the answer to each batch: the session's latest estimate"),
        ("out", "TrackSummary", "the answer to the batch with ``\"end\": true``; then the service "
         "closes the connection (1000)"),
        ("out", "ErrorMessage", "a refused message: ``{\"detail\": \"one line\", \"status\": 422}``, "
         "``status`` the HTTP status the same batch would get over HTTP"),
    ),
    refusals=(
        ("401", "missing or wrong token (header or ``access_token``)"),
        ("404", "no such session (or one whose filter never started: it left no track)"),
        ("410", "the session has ended (its track is saved)"),
    ),
    errors=(
        ("400", "malformed JSON, or a binary frame that is not UTF-8"),
        ("404", "the session has gone (no track left)"),
        ("409", "the session is ending"),
        ("410", "the session has ended (another connection's ``end``, ``DELETE``, or ``--idle-timeout``)"),
        ("422", "rows or values refused; the batch that shows the IMU stream unusable fails the session"),
        ("500", "a bug of the service (the detail names only the exception's type)"),
        ("503", "the service stopped before it could answer"),
    ),
    close_codes=(
        ("1000", "after the answer to ``\"end\": true``: the session has ended, its track is saved"),
        ("1009", "a message over 4 MiB (message too big); the session stays open: reconnect and send "
         "fewer rows per message"),
        ("1012", "the service is stopping; the session ends with the reason ``shutdown``"),
        ("1006", "(in the browser) the handshake was refused: see the refusals above"),
    ),
)


def api_reference_html(schema: dict[str, Any], swagger_url: str = "/docs/swagger",
                       openapi_url: str = "/openapi.json", websockets: Sequence[WebSocketDoc] = ()) -> str:
    """The API reference page of an OpenAPI ``schema`` (as ``FastAPI.openapi()`` returns it).

    Parameters
    ----------
    schema
        The OpenAPI document.
    swagger_url, openapi_url
        Where the service serves Swagger UI and the schema (linked from the page).
    websockets
        The service's WebSocket routes, which the schema leaves out.

    Returns
    -------
    str
        A whole HTML document: every operation with its parameters, request body and responses (each
        route's own errors), every WebSocket route with its messages, errors and close codes, then every
        component schema with its fields.
    """
    info = schema.get("info", {})
    title = f"{info.get('title', 'API')} {info.get('version', '')}".strip()
    parts = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{_e(title)}: API reference</title><style>{_STYLE}</style></head><body>",
        f"<h1>{_e(title)}</h1>",
        f'<p class="d">{_text(info.get("summary", ""))}\n{_text(info.get("description", ""))}</p>',
        f'<p>The schema: <a href="{_e(openapi_url)}"><code>{_e(openapi_url)}</code></a>. Interactive page: '
        f'<a href="{_e(swagger_url)}">Swagger UI</a> (your browser loads it from the jsDelivr CDN). '
        '<span class="tok">token</span> marks a route that needs the service\'s token '
        "(<code>Authorization: Bearer TOKEN</code>) when it has one.</p>",
        "<h2>Routes</h2>",
    ]
    parts.extend(_operation(path, method, item[method]) for path, item in schema.get("paths", {}).items()
                 for method in _METHODS if method in item)
    if websockets:
        parts.append("<h2>WebSocket</h2>")
        parts.extend(_websocket(doc) for doc in websockets)
    components = schema.get("components", {}).get("schemas", {})
    if components:
        parts.append("<h2>Schemas</h2>")
        parts.extend(_component(name, body) for name, body in components.items())
    parts.append("</body></html>")
    return "\n".join(parts)


def _heading(anchor: str, method: str, label: str, path: str, token: bool) -> str:
    lock = ' <span class="tok" title="needs the service\'s token">token</span>' if token else ""
    return f'<h3 id="{_e(anchor)}"><span class="m {method}">{label}</span> {_e(path)}{lock}</h3>'


def _operation(path: str, method: str, op: dict[str, Any]) -> str:
    out = [_heading(op.get("operationId", method + path), method, method.upper(), path,
                    bool(op.get("security")))]
    if op.get("summary"):
        out.append(f"<p><b>{_text(op['summary'])}</b></p>")
    if op.get("description"):
        out.append(f'<p class="d">{_text(op["description"])}</p>')
    params = op.get("parameters", [])
    if params:
        rows = [(f"<code>{_e(p['name'])}</code>", _e(p.get("in", "")), "yes" if p.get("required") else "no",
                 _type_of(p.get("schema", {})), _text(_description(p)))
                for p in params]
        out.append(_table(("parameter", "in", "required", "type", "description"), rows))
    body = op.get("requestBody")
    if body:
        rows = [(f"<code>{_e(kind)}</code>", _type_of(media.get("schema", {})))
                for kind, media in body.get("content", {}).items()]
        out.append(_table(("request body", "schema"), rows))
    responses = op.get("responses", {})
    rows = [(f"<code>{_e(status)}</code>", _text(responses[status].get("description", "")),
             _bodies(responses[status]))
            for status in sorted(responses)]  # the route's own errors, each with when it is sent
    if rows:
        out.append(_table(("status", "meaning", "body"), rows))
    return "\n".join(out)


def _websocket(doc: WebSocketDoc) -> str:
    params = [(f"<code>{_e(name)}</code>", _e(where), _e(required), _text(what))
              for name, where, required, what in doc.parameters]
    messages = [(_e(way), _type_of({"$ref": f"#/components/schemas/{name}"}) if name else "", _text(when))
                for way, name, when in doc.messages]
    out = [_heading("websocket" + doc.path, "ws", "WS", doc.path, doc.token),
           f"<p><b>{_text(doc.summary)}</b></p>", f'<p class="d">{_text(doc.description)}</p>',
           _table(("parameter", "in", "required", "description"), params),
           _table(("message", "schema", "when"), messages)]
    for header, codes in (("handshake refused", doc.refusals), ("error message", doc.errors),
                          ("close code", doc.close_codes)):
        rows = [(f"<code>{_e(code)}</code>", _text(when)) for code, when in codes]
        out.append(_table((header, "when"), rows))
    return "\n".join(out)


def _description(item: dict[str, Any]) -> str:
    return item.get("description", item.get("schema", {}).get("description", ""))


def _bodies(response: dict[str, Any]) -> str:
    """The response's bodies: each schema's type, or the media type of a file (a binary string)."""
    return ", ".join(f"<code>{_e(kind)}</code>" if m.get("schema", {}).get("format") == "binary"
                     else _type_of(m.get("schema", {})) for kind, m in response.get("content", {}).items())


def _component(name: str, body: dict[str, Any]) -> str:
    out = [f'<h3 id="schema-{_e(name)}">{_e(name)}</h3>']
    if body.get("description"):
        out.append(f'<p class="d">{_text(body["description"])}</p>')
    required = set(body.get("required", []))
    rows = []
    for field, spec in body.get("properties", {}).items():
        default = f"<code>{_e(json.dumps(spec['default']))}</code>" if "default" in spec else ""
        rows.append((f"<code>{_e(field)}</code>", _type_of(spec), "yes" if field in required else "no",
                     default, _text(spec.get("description", ""))))
    if rows:
        out.append(_table(("field", "type", "required", "default", "description"), rows))
    elif "enum" in body or "type" in body:
        out.append(f"<p>{_type_of(body)}</p>")
    return "\n".join(out)


def _type_of(spec: dict[str, Any]) -> str:
    """A schema's type as HTML: a link for a reference, ``a | b`` for a union, ``array of x``."""
    if "$ref" in spec:
        name = spec["$ref"].rsplit("/", 1)[-1]
        return f'<a href="#schema-{_e(name)}">{_e(name)}</a>'
    for key in ("anyOf", "oneOf", "allOf"):
        if key in spec:
            return " | ".join(_type_of(s) for s in spec[key])
    if "enum" in spec:
        return "one of " + ", ".join(f"<code>{_e(json.dumps(v))}</code>" for v in spec["enum"])
    kind = spec.get("type", "any")
    if kind == "array":
        return f"array of {_type_of(spec.get('items', {}))}"
    if kind == "object" and isinstance(spec.get("additionalProperties"), dict):
        return f"object of {_type_of(spec['additionalProperties'])}"
    return _e(f"{kind} ({spec['format']})" if "format" in spec else str(kind))


def _table(header: tuple[str, ...], rows: list[tuple[str, ...]]) -> str:
    head = "".join(f"<th>{h}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f'<div class="scroll"><table><tr>{head}</tr>{body}</table></div>'


def _e(text: object) -> str:
    return html.escape(str(text), quote=True)


def _text(text: object) -> str:
    """Prose from a docstring or a description as HTML: escaped, ``double backticks`` as code."""
    return re.sub(r"``(.+?)``", r"<code>\1</code>", _e(text), flags=re.S)


def swagger_ui_html(openapi_url: str, title: str, reference_url: str = "/docs",
                    js_url: str = SWAGGER_JS_URL, css_url: str = SWAGGER_CSS_URL) -> str:
    """Swagger UI's page, which the browser loads from a CDN, saying so where it cannot.

    FastAPI's page calls ``SwaggerUIBundle`` whether its script came or not: offline, a blank page.
    This one starts Swagger UI only once its script has loaded; until then, and for good where it
    fails, the page says what it waits for and links to the reference that needs nothing outside.

    Parameters
    ----------
    openapi_url
        The schema Swagger UI draws.
    title
        The page's title.
    reference_url
        The offline API reference (:func:`api_reference_html`).
    js_url, css_url
        Swagger UI's script and style.

    Returns
    -------
    str
        A whole HTML document.
    """
    back = f'<a href="{_e(reference_url)}">the API reference</a>'
    waiting = (f"Swagger UI loads from {_e(js_url.split('/')[2])}. If nothing appears, use {back}, "
               "which needs nothing from outside the service.")
    failed = (f"Swagger UI could not be loaded from {_e(js_url.split('/')[2])} (offline, or blocked). "
              f"The same API is described by {back}, which needs nothing from outside the service.")
    config = json.dumps({"url": openapi_url, "dom_id": "#swagger-ui", "layout": "BaseLayout",
                         "deepLinking": True, "showExtensions": True, "showCommonExtensions": True})
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{_e(title)}</title>
<link rel="stylesheet" href="{_e(css_url)}">
<style>.note{{font:16px/1.45 system-ui,sans-serif;margin:2rem;max-width:40rem}}</style>
</head><body>
<div id="swagger-ui"><p class="note" id="swagger-note">{waiting}</p></div>
<template id="swagger-failed"><p class="note" id="swagger-note" role="alert">{failed}</p></template>
<script>
function swaggerFailed() {{
  const note = document.getElementById("swagger-failed").content.cloneNode(true);
  document.getElementById("swagger-ui").replaceChildren(note);
}}
function swaggerLoaded() {{
  if (typeof SwaggerUIBundle === "undefined") {{ swaggerFailed(); return; }}
  const config = {config};
  config.presets = [SwaggerUIBundle.presets.apis, SwaggerUIBundle.SwaggerUIStandalonePreset];
  window.ui = SwaggerUIBundle(config);
}}
</script>
<script src="{_e(js_url)}" onload="swaggerLoaded()" onerror="swaggerFailed()"></script>
</body></html>
"""
