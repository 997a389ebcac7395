"""Who the served dashboard answers: the Host header check against DNS rebinding.

A page on another site can re-bind its own name to 127.0.0.1 and then reach a server on the
user's loopback interface under that name: the browser sees the same origin (Origin = Host =
the attacker's name), so Bokeh's websocket origin allowlist is not consulted (Tornado skips the
check for same-origin requests). The server therefore refuses, before any handler runs, every
HTTP or websocket request whose ``Host`` header names something it does not serve, as Jupyter
does (``notebook.base.handlers.IPythonHandler.check_host``):

- ``localhost`` and loopback addresses (``127.0.0.1``, ``[::1]``), with any port (an SSH
  tunnel may forward another port);
- names given with ``baarda serve --allow-host NAME`` (a proxy's name, the machine's DNS name);
- served on a non-loopback address (``--address``), any IP address written as such (a name that
  is an address cannot be re-bound) and the machine's own host names.

A refused request gets ``403`` and one line of text.
"""

from __future__ import annotations

import ipaddress
import re
import socket

import tornado.web
from bokeh.protocol.exceptions import ValidationError
from bokeh.protocol.receiver import Receiver

REFUSED = ("baarda: refused: this server does not serve the host named in the request "
           "(start it with --allow-host NAME to serve NAME)\n")
_HOST = re.compile(r"(\[[0-9A-Fa-f:.]+\]|[^:\[\]\s]+)(?::(\d{1,5}))?")


def is_loopback(address: str) -> bool:
    """True for ``localhost`` and loopback IP addresses."""
    if address.strip().lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(address.strip("[]")).is_loopback
    except ValueError:
        return False


class HostCheck:
    """``check(host_header)``: whether a request naming ``host_header`` is served (module
    docstring). ``names``: the ``--allow-host`` names; ``remote``: served on a non-loopback
    address."""

    def __init__(self, names=(), remote: bool = False):
        self.remote = bool(remote)
        self.names = {"localhost"} | {str(n).strip().lower().rstrip(".") for n in names if str(n).strip()}
        if self.remote:
            for name in (socket.gethostname(), socket.getfqdn()):
                if name:
                    self.names.add(name.lower().rstrip("."))

    def __call__(self, host: str | None) -> bool:
        if host is None:            # HTTP/1.0 without a Host header (no browser sends that)
            return True
        m = _HOST.fullmatch(host.strip().lower())
        if m is None:
            return False
        name = m.group(1)
        if name.startswith("["):
            name = name[1:-1]
        try:
            addr = ipaddress.ip_address(name)
        except ValueError:
            return name.rstrip(".") in self.names
        return addr.is_loopback or self.remote


class Refused(tornado.web.RequestHandler):
    """Answers a request for a host the server does not serve: 403 and one line of text."""

    def prepare(self):
        self.set_status(403)
        self.set_header("Content-Type", "text/plain; charset=utf-8")
        self.finish(REFUSED)


def guard_hosts(server, check: HostCheck) -> None:
    """Make the Bokeh ``server`` refuse (:class:`Refused`) every request, page or websocket,
    whose Host header ``check`` does not accept, before Bokeh's handlers see it."""
    app = server._tornado            # the tornado.web.Application (bokeh.server.tornado.BokehTornado)
    find = app.find_handler

    def find_handler(request, **kwargs):
        if not check(request.headers.get("Host")):
            return app.get_handler_delegate(request, Refused)
        return find(request, **kwargs)

    app.find_handler = find_handler


def bound_messages(max_bytes: int) -> None:
    """Let a Bokeh message carry at most ``max_bytes`` in its binary buffers: Bokeh's
    :class:`bokeh.protocol.receiver.Receiver` keeps every buffer of a message until the number
    its header announces has arrived; past the bound the message is a protocol error and the
    connection is closed (what was held is dropped). Tornado bounds each frame
    (``websocket_max_message_size``). Process-wide; idempotent (the tighter bound stays)."""
    current = getattr(Receiver, "_baarda_max_bytes", None)
    Receiver._baarda_max_bytes = int(max_bytes) if current is None else min(current, int(max_bytes))
    if current is not None:
        return
    header, payload = Receiver._HEADER, Receiver._BUFFER_PAYLOAD

    def _HEADER(self, fragment):
        self._baarda_held = 0
        return header(self, fragment)

    def _BUFFER_PAYLOAD(self, fragment):
        held = getattr(self, "_baarda_held", 0) + (len(fragment) if isinstance(fragment, bytes) else 0)
        if held > Receiver._baarda_max_bytes:
            self._partial = None
            self._fragments = []
            self._current_consumer = self._HEADER
            raise ValidationError(f"a message of more than {Receiver._baarda_max_bytes} bytes of buffers")
        self._baarda_held = held
        return payload(self, fragment)

    _HEADER.__name__, _BUFFER_PAYLOAD.__name__ = "_HEADER", "_BUFFER_PAYLOAD"
    Receiver._HEADER, Receiver._BUFFER_PAYLOAD = _HEADER, _BUFFER_PAYLOAD
