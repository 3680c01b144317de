"""Sending a stored track's file from a file the route has already opened, for GET and HEAD.

Starlette's ``FileResponse`` opens its path only when it sends, after the route has returned: a
``DELETE /tracks/{id}`` or a retention pass in between made the download a 500. An open file outlives
its removal (POSIX), so a download that has started sends the whole file.

Byte ranges follow RFC 9110 section 14: one range is a 206 with ``Content-Range``, several a 206
``multipart/byteranges``. Several ranges are bounded (section 17.15: many small or overlapping
ranges cost the server far more than the client): at most :data:`MAX_RANGES`, each after the one
before it, and ranges that overlap or lie closer than a part's own headers are sent as one.
"""

from __future__ import annotations

import os
import re
import secrets
from email.utils import formatdate
from typing import BinaryIO

import anyio.to_thread
from starlette.datastructures import Headers, MutableHeaders
from starlette.responses import Response
from starlette.types import Receive, Scope, Send

#: One range of a ``Range: bytes=...`` set: ``FIRST-LAST``, ``FIRST-`` or ``-SUFFIX_LENGTH``. Longer
#: numbers than any file's size are malformed (``int()`` refuses over 4300 digits: that was a 500).
_RANGE_SPEC = re.compile(r"(\d{0,18})-(\d{0,18})")

#: Most ranges one request may ask for; more get the whole file.
MAX_RANGES = 16

#: Ranges closer than this are sent as one part: each part costs about as much in its own headers.
MERGE_GAP_BYTES = 100

#: A file span ``(start, end)``, bytes ``[start, end)``, or bytes sent as they are (multipart framing).
Piece = tuple[int, int] | bytes


class OpenFileResponse(Response):
    """A file sent from a file object the route opened; the response closes it once sent.

    ``Range: bytes=0-99`` (``100-``, ``-100``) gets a 206 with those bytes; several ranges
    (``bytes=0-99,5000-5099``) a 206 ``multipart/byteranges``, in the order asked, those that overlap
    or lie within :data:`MERGE_GAP_BYTES` merged; a set none of which starts before the end a 416. A
    malformed ``Range``, more than :data:`MAX_RANGES` ranges, a range that starts before the one
    before it, or an ``If-Range`` that names neither this file's ETag nor its date get the whole file
    (200), as RFC 9110 allows. A HEAD request gets the headers the GET would get and no body.

    Parameters
    ----------
    file
        The file, open for binary reading (the response owns it).
    media_type
        Its ``Content-Type``.
    """

    chunk_size = 64 * 1024

    def __init__(self, file: BinaryIO, media_type: str) -> None:
        self.file = file
        stat = os.fstat(file.fileno())
        self.size = stat.st_size
        self.status_code = 200
        self.media_type = media_type
        self.background = None
        headers = {
            "accept-ranges": "bytes",
            "last-modified": formatdate(stat.st_mtime, usegmt=True),
            "etag": f'"{stat.st_mtime_ns:x}-{stat.st_size:x}"',
        }
        self.init_headers(headers)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        try:
            status, spans = self._spans(Headers(scope=scope))
            headers, pieces = self._framing(status, spans)
            await send({"type": "http.response.start", "status": status, "headers": headers.raw})
            if scope["method"] != "HEAD":
                for piece in pieces:
                    await self._send_piece(piece, send)
            await send({"type": "http.response.body", "body": b"", "more_body": False})
        finally:
            self.file.close()

    async def _send_piece(self, piece: Piece, send: Send) -> None:
        if isinstance(piece, bytes):
            await send({"type": "http.response.body", "body": piece, "more_body": True})
            return
        sent, end = piece
        self.file.seek(sent)
        while sent < end:
            chunk = await anyio.to_thread.run_sync(self.file.read, min(self.chunk_size, end - sent))
            if not chunk:
                return
            sent += len(chunk)
            await send({"type": "http.response.body", "body": chunk, "more_body": True})

    def _spans(self, request: Headers) -> tuple[int, list[tuple[int, int]]]:
        """The status and the file spans ``[start, end)`` to send for the request's ``Range``."""
        whole = 200, [(0, self.size)]
        unit, _, ranges = request.get("range", "").replace(" ", "").partition("=")
        if_range = request.get("if-range")
        if unit != "bytes" or (if_range is not None and if_range not in (self.headers["etag"],
                                                                         self.headers["last-modified"])):
            return whole
        specs = ranges.split(",")
        if len(specs) > MAX_RANGES:
            return whole
        spans: list[tuple[int, int]] = []
        for spec in specs:
            span = self._span(spec)
            if span is None:
                return whole
            start, end = span
            if start >= self.size:  # unsatisfiable: left out
                continue
            if spans and start < spans[-1][0]:
                return whole
            if spans and start <= spans[-1][1] + MERGE_GAP_BYTES:
                spans[-1] = spans[-1][0], max(end, spans[-1][1])
            else:
                spans.append((start, end))
        return (206, spans) if spans else (416, [])

    def _span(self, spec: str) -> tuple[int, int] | None:
        """The bytes ``[start, end)`` of one range (``start`` past the end if unsatisfiable), or
        ``None`` if it is malformed."""
        match = _RANGE_SPEC.fullmatch(spec)
        if match is None or match.groups() == ("", ""):
            return None
        first, last = match.groups()
        if not first:  # the last LAST bytes
            return max(0, self.size - int(last)), self.size
        if last and int(last) < int(first):
            return None
        return int(first), min(int(last) + 1, self.size) if last else self.size

    def _framing(self, status: int, spans: list[tuple[int, int]]) -> tuple[MutableHeaders, list[Piece]]:
        """The headers and the body's pieces of a reply with ``status`` sending ``spans``."""
        headers = MutableHeaders(raw=list(self.raw_headers))
        pieces: list[Piece] = list(spans)
        if status == 416:
            headers["content-range"] = f"bytes */{self.size}"
        elif status == 206 and len(spans) == 1:
            headers["content-range"] = f"bytes {spans[0][0]}-{spans[0][1] - 1}/{self.size}"
        elif status == 206:
            boundary = secrets.token_hex(16)
            part_type = headers["content-type"]
            headers["content-type"] = f"multipart/byteranges; boundary={boundary}"
            pieces = []
            for start, end in spans:
                head = (f"--{boundary}\r\nContent-Type: {part_type}\r\n"
                        f"Content-Range: bytes {start}-{end - 1}/{self.size}\r\n\r\n").encode()
                pieces += [b"\r\n" + head if pieces else head, (start, end)]
            pieces.append(f"\r\n--{boundary}--\r\n".encode())
        headers["content-length"] = str(sum(len(p) if isinstance(p, bytes) else p[1] - p[0] for p in pieces))
        return headers, pieces
