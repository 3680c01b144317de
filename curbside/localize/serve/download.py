"""Sending a stored track's file from a file the route has already opened.

Starlette's ``FileResponse`` opens its path only when it sends, after the route has returned: a
``DELETE /tracks/{id}`` or a retention pass in between made the download a 500. An open file outlives
its removal (POSIX), so a download that has started sends the whole file.
"""

from __future__ import annotations

import os
import re
from email.utils import formatdate
from typing import BinaryIO

import anyio.to_thread
from starlette.datastructures import Headers, MutableHeaders
from starlette.responses import Response
from starlette.types import Receive, Scope, Send

#: One byte range: ``bytes=FIRST-LAST``, ``bytes=FIRST-`` or ``bytes=-SUFFIX_LENGTH``.
_ONE_RANGE = re.compile(r"bytes=(\d*)-(\d*)")


class OpenFileResponse(Response):
    """A file sent from a file object the route opened; the response closes it once sent.

    A single byte range (``Range: bytes=0-99``, ``100-``, ``-100``) gets a 206 with those bytes, and
    one that starts past the end a 416. Several ranges, a malformed ``Range``, or an ``If-Range`` that
    names neither this file's ETag nor its date get the whole file (200), as RFC 9110 allows.

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
            status, start, end = self._span(Headers(scope=scope))
            headers = MutableHeaders(raw=list(self.raw_headers))
            headers["content-length"] = str(end - start)
            if status == 206:
                headers["content-range"] = f"bytes {start}-{end - 1}/{self.size}"
            elif status == 416:
                headers["content-range"] = f"bytes */{self.size}"
            await send({"type": "http.response.start", "status": status, "headers": headers.raw})
            self.file.seek(start)
            sent = start
            while True:
                chunk = await anyio.to_thread.run_sync(self.file.read, min(self.chunk_size, end - sent))
                sent += len(chunk)
                more = bool(chunk) and sent < end
                await send({"type": "http.response.body", "body": chunk, "more_body": more})
                if not more:
                    break
        finally:
            self.file.close()

    def _span(self, request: Headers) -> tuple[int, int, int]:
        """The status and the bytes ``[start, end)`` to send for the request's ``Range``."""
        whole = (200, 0, self.size)
        match = _ONE_RANGE.fullmatch(request.get("range", "").replace(" ", ""))
        if_range = request.get("if-range")
        if match is None or (if_range is not None and if_range not in (self.headers["etag"],
                                                                         self.headers["last-modified"])):
            return whole
        first, last = match.groups()
        if not first:  # the last LAST bytes
            if not last:
                return whole
            start, end = max(0, self.size - int(last)), self.size
        else:
            start, end = int(first), self.size if not last else min(int(last) + 1, self.size)
            if last and int(last) < start:
                return whole
        if start >= self.size:
            return 416, 0, 0
        return 206, start, end
