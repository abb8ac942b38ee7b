"""The view's check that ``--host`` / ``--port`` can be bound (``--joints`` and ``--part-pose``
are read by :mod:`cellsight.model.arguments`)."""

from __future__ import annotations

import errno
import socket

from cellsight.errors import CellsightError, short_repr


def check_port(host: str, port: int) -> None:
    """A :class:`CellsightError` unless ``host:port`` can be bound now (the web server would
    otherwise quietly move to another port); port 0 lets the system pick a free one."""
    if not 0 <= port <= 65535:
        raise CellsightError(f"--port: expected a port number in 0..65535, got {port}")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as exc:
        raise CellsightError(f"--host: cannot resolve {short_repr(host)} ({exc})") from exc
    family, kind, proto, _, address = infos[0]
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server does
        try:
            probe.bind(address)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise CellsightError(f"--port: {host}:{port} is already in use (another "
                                     f"'cellsight view'? pick another --port)") from exc
            raise CellsightError(f"--host/--port: cannot listen on {host}:{port} "
                                 f"({exc.strerror or exc})") from exc
