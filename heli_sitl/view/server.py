"""The viser server every view runs on: loopback only, quiet, no browser opened (the page's
address is printed by the command that starts it)."""

from __future__ import annotations

import contextlib
import io
import logging

import viser

HOST = "127.0.0.1"
DEFAULT_PORT = 8080  # viser's own default; --view-port / --port to change it


def start_server(port: int = DEFAULT_PORT) -> viser.ViserServer:
    """A viser server on 127.0.0.1:``port`` (0: the kernel's choice; ``get_port()``)."""
    logging.getLogger("websockets").setLevel(logging.ERROR)
    # viser draws a banner on stdout even when not verbose: the commands print their own line
    with contextlib.redirect_stdout(io.StringIO()):
        server = viser.ViserServer(host=HOST, port=port, verbose=False)
    return server


def url_of(server: viser.ViserServer) -> str:
    return f"http://{server.get_host()}:{server.get_port()}/"
