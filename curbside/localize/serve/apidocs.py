"""The service's API reference as one self-contained HTML page, drawn from its OpenAPI schema.

FastAPI's own ``/docs`` page is Swagger UI, which the browser loads from a CDN: offline, or on a
network that blocks it, the page is blank. This page needs nothing but itself (no script, no outside
style or font), so it reads wherever the service runs. The interactive Swagger UI stays at
``/docs/swagger`` for those who can load it.
"""

from __future__ import annotations

import html
import json
from typing import Any

_METHODS = ("get", "head", "post", "put", "patch", "delete")

_STYLE = """
body{font:15px/1.45 system-ui,sans-serif;margin:0 auto;max-width:60rem;padding:1rem;color:#222}
h1{font-size:1.5rem;margin-bottom:.2rem}h2{margin-top:2rem;border-bottom:1px solid #ccc}
h3{font-size:1.05rem;margin:1.4rem 0 .3rem;font-family:ui-monospace,monospace;word-break:break-all}
.m{display:inline-block;min-width:4.2em;padding:0 .4em;border-radius:3px;color:#fff;text-align:center}
.get{background:#1f6feb}.head{background:#0a7ea4}.post{background:#2da44e}.put,.patch{background:#bf8700}
.delete{background:#cf222e}
.tok{font:600 .75rem system-ui,sans-serif;color:#8250df;border:1px solid #8250df;border-radius:3px;
padding:0 .3em}
.scroll{overflow-x:auto}table{border-collapse:collapse;margin:.3rem 0 .8rem}
td,th{border:1px solid #ddd;padding:.2rem .5rem;text-align:left;vertical-align:top}
th{background:#f6f8fa}code{font-family:ui-monospace,monospace;font-size:.92em}
p.d{white-space:pre-wrap;margin:.3rem 0}
"""


def api_reference_html(schema: dict[str, Any], swagger_url: str = "/docs/swagger",
                       openapi_url: str = "/openapi.json") -> str:
    """The API reference page of an OpenAPI ``schema`` (as ``FastAPI.openapi()`` returns it).

    Parameters
    ----------
    schema
        The OpenAPI document.
    swagger_url, openapi_url
        Where the service serves Swagger UI and the schema (linked from the page).

    Returns
    -------
    str
        A whole HTML document: every operation with its parameters, request body and responses, then
        every component schema with its fields.
    """
    info = schema.get("info", {})
    title = f"{info.get('title', 'API')} {info.get('version', '')}".strip()
    parts = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{_e(title)}: API reference</title><style>{_STYLE}</style></head><body>",
        f"<h1>{_e(title)}</h1>",
        f'<p class="d">{_e(info.get("summary", ""))}\n{_e(info.get("description", ""))}</p>',
        f'<p>The schema: <a href="{_e(openapi_url)}"><code>{_e(openapi_url)}</code></a>. Interactive page: '
        f'<a href="{_e(swagger_url)}">Swagger UI</a> (your browser loads it from the jsDelivr CDN). '
        '<span class="tok">token</span> marks a route that needs the service\'s token '
        "(<code>Authorization: Bearer TOKEN</code>) when it has one.</p>",
        "<h2>Routes</h2>",
    ]
    operations = [(path, method, item[method]) for path, item in schema.get("paths", {}).items()
                  for method in _METHODS if method in item]
    # the error statuses every route declares share one row; one route's own (416) has its own
    declared = [set(op.get("responses", {})) for *_, op in operations]
    shared = set.intersection(*declared) if declared else set()
    parts.extend(_operation(path, method, op, shared) for path, method, op in operations)
    components = schema.get("components", {}).get("schemas", {})
    if components:
        parts.append("<h2>Schemas</h2>")
        parts.extend(_component(name, body) for name, body in components.items())
    parts.append("</body></html>")
    return "\n".join(parts)


def _operation(path: str, method: str, op: dict[str, Any], shared: set[str]) -> str:
    lock = ' <span class="tok" title="needs the service\'s token">token</span>' if op.get("security") else ""
    out = [f'<h3 id="{_e(op.get("operationId", method + path))}"><span class="m {method}">'
           f"{method.upper()}</span> {_e(path)}{lock}</h3>"]
    if op.get("summary"):
        out.append(f"<p><b>{_e(op['summary'])}</b></p>")
    if op.get("description"):
        out.append(f'<p class="d">{_e(op["description"])}</p>')
    params = op.get("parameters", [])
    if params:
        rows = [(f"<code>{_e(p['name'])}</code>", _e(p.get("in", "")), "yes" if p.get("required") else "no",
                 _type_of(p.get("schema", {})), _e(_description(p)))
                for p in params]
        out.append(_table(("parameter", "in", "required", "type", "description"), rows))
    body = op.get("requestBody")
    if body:
        rows = [(f"<code>{_e(kind)}</code>", _type_of(media.get("schema", {})))
                for kind, media in body.get("content", {}).items()]
        out.append(_table(("request body", "schema"), rows))
    responses = op.get("responses", {})
    errors = {status: resp for status, resp in responses.items()
              if status.startswith(("4", "5")) and status in shared}
    rows = [(f"<code>{_e(status)}</code>", _e(resp.get("description", "")), _bodies(resp))
            for status, resp in responses.items() if status not in errors]
    if errors:  # every route declares the same error statuses: one row, not ten
        codes = ", ".join(f'<code title="{_e(_description(r))}">{_e(s)}</code>' for s, r in errors.items())
        bodies = " | ".join(sorted({_bodies(r) for r in errors.values()}))
        rows.append((codes, "an error (its detail says what went wrong)", bodies))
    if rows:
        out.append(_table(("status", "meaning", "body"), rows))
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
        out.append(f'<p class="d">{_e(body["description"])}</p>')
    required = set(body.get("required", []))
    rows = []
    for field, spec in body.get("properties", {}).items():
        default = f"<code>{_e(json.dumps(spec['default']))}</code>" if "default" in spec else ""
        rows.append((f"<code>{_e(field)}</code>", _type_of(spec), "yes" if field in required else "no",
                     default, _e(spec.get("description", ""))))
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
