"""``localize serve``: live tracking over HTTP and WebSocket (see ``docs/service.md``)."""
