"""``localize serve``: the live tracking service (HTTP + WebSocket; see ``docs/service.md``).

::

    localize serve [--map MAP] [--host 127.0.0.1] [--port 8750] [--data-dir DIR] [--token-file FILE]
                   [--mode MODE] [--set KEY=VALUE ...] [--idle-timeout S] [--max-sessions N]
                   [--keep-tracks-days D] [--max-tracks N]

Without ``--map`` it tracks as ``localize run`` does without one. Tracks of ended sessions go to
``DATA_DIR/tracks`` (default: the user's data folder, ``CURBSIDE_DATA_DIR``); they are kept until
``DELETE /tracks/{id}``, or, with ``--keep-tracks-days`` or ``--max-tracks``, until they are older or
beyond the count (checked at start and every minute; the count also as each track is written). With a
token (from ``--token-file`` or ``CURBSIDE_TOKEN``) every request must carry ``Authorization: Bearer
TOKEN``.
"""

from __future__ import annotations

import argparse
import logging
import os
import socket
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from curbside import settings
from curbside.cli.common import add_config_options, config_overrides, port, positive_float, positive_int
from curbside.errors import CurbsideInputError
from curbside.localize.runconstants import MODES

if TYPE_CHECKING:
    from curbside.localize.serve.common import ServiceConfig

logger = logging.getLogger(__name__)

#: Environment variable read for the token when ``--token-file`` is not given.
TOKEN_ENV = "CURBSIDE_TOKEN"


def _token(path: str | None) -> str | None:
    if path is None:
        return os.environ.get(TOKEN_ENV) or None
    try:
        token = Path(path).read_text(encoding="utf-8").strip()
    except OSError as exc:
        raise CurbsideInputError(path, f"cannot read the token file ({exc.strerror or exc})") from None
    if len(token) < 16:
        raise CurbsideInputError(path, "the token must be at least 16 characters")
    return token


def _check_port(host: str, port: int) -> None:
    """Fail early, in one line, when the address cannot be bound."""
    try:
        with socket.create_server((host, port)):
            pass
    except OSError as exc:
        raise CurbsideInputError(f"{host}:{port}", f"cannot listen there ({exc.strerror or exc})") from None


def _data_dir(path: str | None) -> Path:
    folder = Path(path) if path else settings.data_dir
    try:
        (folder / "tracks").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CurbsideInputError(folder, f"cannot create the data folder ({exc.strerror or exc})") from None
    return folder


def _retention(config: ServiceConfig) -> str:
    """How long tracks are kept, for the start-up line (empty: until deleted)."""
    kept = [f"{config.keep_tracks_days:g} days"] if config.keep_tracks_days is not None else []
    kept += [f"the newest {config.max_tracks}"] if config.max_tracks is not None else []
    return f" (kept: {', at most '.join(kept)})" if kept else ""


def _serve(args: argparse.Namespace) -> int:
    import torch
    import uvicorn

    from curbside.localize.serve.app import MAX_BODY_BYTES, create_app
    from curbside.localize.serve.service import ServiceConfig, TrackingService

    _check_port(args.host, args.port)
    torch.set_num_threads(args.threads)
    config = ServiceConfig(
        map_path=args.map,
        data_dir=_data_dir(args.data_dir),
        token=_token(args.token_file),
        mode=args.mode,
        overrides=config_overrides(args),
        idle_timeout_s=args.idle_timeout,
        max_sessions=args.max_sessions,
        keep_tracks_days=args.keep_tracks_days,
        max_tracks=args.max_tracks,
    )
    service = TrackingService(config)
    app = create_app(config, service)
    where = f"map {args.map} ({len(service.places)} sidewalk segments)" if args.map else "no map"
    tracks = f"{config.data_dir / 'tracks'}{_retention(config)}"
    sys.stdout.write(
        f"localize serve: http://{args.host}:{args.port} (OpenAPI page /docs), {where}, mode {config.mode}, "
        f"tracks in {tracks}{', token required' if config.token else ''}\n"
    )
    sys.stdout.flush()
    uvicorn.run(
        app,
        host=args.host,
        port=args.port,
        log_level="info" if args.verbose else "warning",
        ws_max_size=MAX_BODY_BYTES,
        timeout_graceful_shutdown=10,
        access_log=False,  # access lines would carry session ids
    )
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``serve`` to the ``localize`` sub-commands."""
    parser = subparsers.add_parser(
        "serve",
        help="live tracking service: stream IMU and GNSS in, get which side of which street back",
        description="Run the live tracking service (HTTP + WebSocket, OpenAPI page at /docs). Each "
        "session runs RoNIN, footstep detection and the particle filter exactly as localize run does; "
        "tracks of ended sessions are saved under DATA_DIR/tracks.",
        epilog="examples:\n  localize serve --map map.geojson\n"
        "  localize serve --map map.geojson --port 9000 --token-file token.txt --set filter.n_particles=300",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--map", help="map layers GeoJSON (osmseg build); none: no map likelihood")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--port", type=port, default=8750, help="port (default 8750)")
    parser.add_argument(
        "--data-dir",
        help=f"where tracks of ended sessions go, under tracks/ (default $CURBSIDE_DATA_DIR, else "
        f"{settings.data_dir})",
    )
    parser.add_argument(
        "--token-file",
        help=f"file holding the bearer token every request must carry (default: ${TOKEN_ENV}, else none)",
    )
    parser.add_argument(
        "--mode", choices=MODES, default="fused", help="every session's method (default fused)"
    )
    add_config_options(
        parser, "a run.json config parameter for every session, e.g. filter.n_particles=300 (repeatable; "
        "`localize parameters` lists them all)"
    )
    parser.add_argument(
        "--idle-timeout",
        type=positive_float,
        default=300.0,
        help="seconds without a request after which a session ends and its track is saved (default 300)",
    )
    parser.add_argument("--max-sessions", type=positive_int, default=1000,
                        help="open sessions at most (default 1000)")
    parser.add_argument(
        "--keep-tracks-days",
        type=positive_float,
        metavar="D",
        help="remove the service's finished tracks older than D days, at start and every minute "
        "(default: keep them until DELETE /tracks/{id})",
    )
    parser.add_argument(
        "--max-tracks",
        type=positive_int,
        metavar="N",
        help="keep at most the N newest finished tracks, removing the oldest at start, every minute and "
        "as each track is written (default: no limit)",
    )
    parser.add_argument(
        "--threads",
        type=positive_int,
        default=1,
        help="torch threads for RoNIN (default 1: the event loop keeps the other core)",
    )
    parser.set_defaults(func=_serve)
