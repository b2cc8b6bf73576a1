"""Serve the recognition API (FastAPI on uvicorn).

Other settings come from POSEDESC_* environment variables. Every log line, the service's and uvicorn's,
starts with its local time (ISO 8601, ms), level and logger.
"""

from __future__ import annotations

import argparse
import socket
from pathlib import Path
from typing import Any

from posedesc.cli import UserError

LOG_FORMAT = "%(asctime)s.%(msecs)03d %(levelname)s %(name)s: %(message)s"
LOG_DATE = "%Y-%m-%dT%H:%M:%S"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (0.0.0.0: every interface)")
    p.add_argument("--port", type=int, default=8000, help="port to listen on")
    p.add_argument("--data-dir", type=Path, help="store folder (default: POSEDESC_DATA_DIR or data/default)")
    p.add_argument("--models", type=Path, help="models folder (default: POSEDESC_MODELS_DIR or models)")
    p.add_argument(
        "--log-level", default="info", choices=("debug", "info", "warning", "error"), help="uvicorn's"
    )
    p.add_argument(
        "--no-demo",
        action="store_true",
        help="register no demo objects into a new data dir (as POSEDESC_DEMO_OBJECTS=false)",
    )


def log_config(level: str) -> dict[str, Any]:
    """One handler, on the root logger, for every log line: the app's (`service`, `index`, `posedesc`)
    and uvicorn's, whose own handlers (no time of day) are left out; they propagate to it."""
    return {
        "version": 1,
        "disable_existing_loggers": False,
        "formatters": {"timed": {"format": LOG_FORMAT, "datefmt": LOG_DATE}},
        "handlers": {"stderr": {"class": "logging.StreamHandler", "formatter": "timed"}},
        "root": {"handlers": ["stderr"], "level": level.upper()},
        "loggers": {
            name: {"handlers": [], "propagate": True, "level": level.upper()}
            for name in ("uvicorn", "uvicorn.error", "uvicorn.access")
        },
    }


def run(args: argparse.Namespace) -> int:
    import logging.config

    import uvicorn
    from pydantic import ValidationError

    from index.features.embed import MODEL_FILES
    from index.store import EMBEDDED, StoreError, check_location, check_store
    from service.main import create_app
    from service.settings import Settings

    try:
        overrides = {
            "data_dir": args.data_dir,
            "models_dir": args.models,
            "demo_objects": False if args.no_demo else None,
        }
        settings = Settings(**{k: v for k, v in overrides.items() if v is not None})
    except ValidationError as e:
        raise UserError(
            "bad setting: " + "; ".join(f"{x['loc'][0]}: {x['msg']}" for x in e.errors())
        ) from None
    if not any((settings.models_dir / f).is_file() for f in MODEL_FILES.values()):
        raise UserError(
            f"no models in {settings.models_dir}: expected any of {', '.join(MODEL_FILES.values())}"
        )
    try:
        settings.data_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"data dir {settings.data_dir}: {e.strerror or e}") from None
    try:  # here, not in the lifespan: uvicorn would print a start-up failure as a traceback
        if settings.store == EMBEDDED:
            check_store(settings.data_dir)
        else:
            check_location(settings.store)
    except StoreError as e:
        raise UserError(str(e)) from None
    if not 0 < args.port < 65536:
        raise UserError(f"--port {args.port}: not a port")
    sock = listen(args.host, args.port)  # before the models load: a busy port fails at once
    logging.config.dictConfig(log_config(args.log_level))
    logging.getLogger("posedesc").info("listening on %s; loading the models and the store", url(sock))
    app = create_app(settings, url=url(sock))
    # log_config=None: uvicorn keeps the configuration above (its loggers propagate to the root's handler)
    server = uvicorn.Server(uvicorn.Config(app, log_level=args.log_level, log_config=None))
    server.run(sockets=[sock])
    return 0 if server.started else 3  # 3: uvicorn's start-up failure (the lifespan failed)


def listen(host: str, port: int) -> socket.socket:
    """A socket bound to host:port and listening (connections wait in its backlog until the app serves);
    a one-line UserError when the address is unknown or taken."""
    try:
        family, kind, proto, _, addr = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )[0]
    except socket.gaierror as e:
        raise UserError(f"--host {host}: {e.strerror}") from None
    sock = socket.socket(family, kind, proto)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn: no wait after a restart
    try:
        sock.bind(addr)
        sock.listen(2048)
    except OSError as e:
        sock.close()
        raise UserError(f"cannot listen on {host}:{port}: {e.strerror or e}") from None
    return sock


def url(sock: socket.socket) -> str:
    host, port = sock.getsockname()[:2]
    return f"http://[{host}]:{port}" if sock.family == socket.AF_INET6 else f"http://{host}:{port}"
