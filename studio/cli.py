"""`sitrelax serve` (the HTTP API), `sitrelax studio` (the web studio) and `sitrelax
grasshopper` (the Rhino 8 script that calls the API); `main` is the
`sitrelax` command: the solver's subcommands (which compose capture's and posedb's) and these."""

from __future__ import annotations

import argparse
import sys

from capture.cli_output import number

from .loopback import LOOPBACK  # the servers (studio.net: asyncio) load when they run


def _say(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _listening(host: str, port: int):
    """A TCP socket bound to host:port for a server to listen on; OSError naming the address
    (and what to do) when it cannot be bound, such as a port another server holds."""
    import errno
    import socket

    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port,
                                                              type=socket.SOCK_STREAM)[0]
    except socket.gaierror as exc:
        raise OSError(f"Cannot listen on {host!r}: {exc.strerror}") from None
    sock = socket.socket(family, kind, proto)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(address)
    except OSError as exc:
        sock.close()
        hint = " (another server holds it: --port picks another, 0 a free one)" if \
            exc.errno == errno.EADDRINUSE else ""
        raise OSError(f"Cannot listen on {host}:{port}: {exc.strerror}{hint}") from None
    sock.set_inheritable(True)
    return sock


def _cmd_serve(args: argparse.Namespace) -> int:
    import asyncio

    import uvicorn

    from .api import create_app, server_config
    from .net import allowed_names, exposure_warning

    _check_db(args.db)
    warning = exposure_warning(args.host, "API")
    if warning:
        _say(f"sitrelax serve: {warning}")
    app = create_app(args.db, limit=int(args.max_request_mb * 1024 * 1024),
                     time_limit=args.time_limit,
                     hosts=allowed_names(args.host, args.allow_host))
    server = uvicorn.Server(server_config(app, args.host, args.port))
    sock = _listening(args.host, args.port)  # (a port in use: a one-line error, no server)

    async def run() -> None:
        task = asyncio.create_task(server.serve(sockets=[sock]))
        while not server.started and not task.done():
            await asyncio.sleep(0.02)
        if server.started:
            host, port = server.servers[0].sockets[0].getsockname()[:2]
            _say(f"sitrelax serve: listening on http://{host}:{port} (OpenAPI at "
                 f"http://{host}:{port}/openapi.json)")
        await task

    asyncio.run(run())
    return 0


def _cmd_studio(args: argparse.Namespace) -> int:
    import logging

    from .net import exposure_warning
    from .web import Studio

    # a request the studio does not take (anything but GET and its websocket) is closed; no
    # traceback for it on the terminal
    logging.getLogger("websockets.server").setLevel(logging.CRITICAL)
    _check_db(args.db)
    warning = exposure_warning(args.host, "studio")
    if warning:
        _say(f"sitrelax studio: {warning}")
    if args.port:  # (a port in use: the same one-line error as serve's, before any work)
        _listening(args.host, args.port).close()
    studio = Studio(db=args.db, host=args.host, port=args.port, out=args.out,
                    allow_hosts=tuple(args.allow_host))
    _say(f"sitrelax studio: open http://{studio.host}:{studio.port} in a browser "
         "(Ctrl-C stops it)")
    try:
        studio.wait()
    finally:
        studio.stop()
    return 0


def _cmd_grasshopper(args: argparse.Namespace) -> int:
    from importlib.resources import files

    script = files("studio").joinpath("grasshopper.py").read_text(encoding="utf-8")
    if args.output:
        from pathlib import Path

        Path(args.output).write_text(script, encoding="utf-8")
        _say(f"sitrelax grasshopper: wrote {args.output}")
    else:
        sys.stdout.write(script)
    return 0


def _check_db(db: str | None) -> None:
    if db is None:
        return
    from pathlib import Path

    from posedb import PoseLibrary

    if not Path(db).exists():
        raise FileNotFoundError(2, "No such pose library", db)
    PoseLibrary(db)  # opens and checks it


def _allow_host(parser) -> None:
    parser.add_argument("--allow-host", action="append", default=[], metavar="NAME",
                        help="a Host/Origin name to answer besides the loopback names and "
                             "--host (repeat it); others get 403")


def register(sub) -> None:
    serve = sub.add_parser("serve", help="the solver as a JSON HTTP API (OpenAPI at "
                                         "/openapi.json)")
    serve.add_argument("--db", help="pose library (HDF5) the API reads poses from")
    serve.add_argument("--host", default=LOOPBACK,
                       help=f"address to listen on (default {LOOPBACK}, this machine only)")
    serve.add_argument("--port", type=number(0, 65535, whole=True), default=8765, help="port (default 8765; 0 picks "
                                                              "a free one)")
    serve.add_argument("--max-request-mb", type=number(0, 4096, low_open=True), default=8.0,
                       help="largest request body accepted, MB (default 8; larger: 413)")
    serve.add_argument("--time-limit", type=number(0, low_open=True), default=60.0,
                       help="seconds of computing a request may take (default 60; longer: "
                            "stopped, 413)")
    _allow_host(serve)
    serve.set_defaults(func=_cmd_serve)
    studio = sub.add_parser("studio", help="the interactive design studio in the browser")
    studio.add_argument("--db", help="pose library (HDF5) to pick people from and save to")
    studio.add_argument("--host", default=LOOPBACK,
                        help=f"address to listen on (default {LOOPBACK}, this machine only)")
    studio.add_argument("--port", type=number(0, 65535, whole=True), default=8080, help="port (default 8080; 0 picks "
                                                               "a free one)")
    studio.add_argument("--out", default="sitrelax-studio",
                        help="folder that Export and Save TOML write into (made if missing)")
    _allow_host(studio)
    studio.set_defaults(func=_cmd_studio)
    gh = sub.add_parser("grasshopper", help="print the Rhino 8 Grasshopper script (Python 3) "
                                            "that fits through `sitrelax serve` into a SubD")
    gh.add_argument("-o", "--output", metavar="FILE", help="write it to FILE instead")
    gh.set_defaults(func=_cmd_grasshopper)


def _bench_cases() -> list:
    from . import bench  # the solver's pipelines: loaded when the benchmarks run

    return bench.cases()


def main(argv: list[str] | None = None) -> int:
    from solver import bench as solver_bench
    from solver import cli as solver_cli

    solver_bench.register_cases(_bench_cases)
    return solver_cli.run(solver_cli.build_parser(extra=register), argv)


if __name__ == "__main__":
    sys.exit(main())
