"""The check that a server's address can be bound: the view's ``--host`` / ``--port``, a run's
``--live`` (``--joints`` and ``--part-pose`` are read by :mod:`cellsight.model.arguments`)."""

from __future__ import annotations

import errno
import socket

from cellsight.errors import CellsightError, short_repr


def check_port(host: str, port: int, port_option: str = "--port",
               host_option: str = "--host") -> None:
    """A :class:`CellsightError` naming the options unless ``host:port`` can be bound now (the
    web server would otherwise quietly move to another port, a live stream fail mid-run);
    port 0 lets the system pick a free one."""
    if not 0 <= port <= 65535:
        raise CellsightError(f"{port_option}: expected a port number in 0..65535, got {port}")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as exc:
        raise CellsightError(f"{host_option}: cannot resolve {short_repr(host)} ({exc})") from exc
    family, kind, proto, _, address = infos[0]
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server does
        try:
            probe.bind(address)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise CellsightError(f"{port_option}: {host}:{port} is already in use (another "
                                     f"cellsight? pick another port, or 0 for a free one)"
                                     ) from exc
            options = port_option if port_option == host_option else (
                f"{host_option}/{port_option}")
            raise CellsightError(f"{options}: cannot listen on {host}:{port} "
                                 f"({exc.strerror or exc})") from exc
