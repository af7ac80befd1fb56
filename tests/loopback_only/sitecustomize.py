"""Loopback only: a connection or a name lookup for any host but this machine is refused at once.

The tests' ``conftest.py`` applies :func:`guarded` to the test process for every test, and puts this
folder first on ``PYTHONPATH``, so that every Python process the tests start (``featmap`` and ``dask``
commands, a LocalCluster's worker processes) imports this file at start-up (Python's ``sitecustomize``
hook) and is guarded too. The code under test then takes its offline path (e.g. an overview falls back
to the ground truth with a warning) and no test depends on, or sends traffic to, the outside.
"""

from __future__ import annotations

import ipaddress
import socket


def is_loopback(host) -> bool:
    """True for this machine's names and loopback addresses (IPv4, IPv6, with or without a zone)."""
    if host in (None, "", b"", "localhost", b"localhost"):
        return True
    try:
        return ipaddress.ip_address((host.decode() if isinstance(host, bytes) else str(host)).split("%")[0]).is_loopback
    except ValueError:
        return False


def is_address(host) -> bool:
    """``host`` is a numeric IPv4 or IPv6 address (resolving it sends nothing; connecting is another matter)."""
    try:
        ipaddress.ip_address((host.decode() if isinstance(host, bytes) else str(host)).split("%")[0])
    except ValueError:
        return False
    return True


def guarded() -> dict[str, tuple[object, str, object]]:
    """The replacements, as ``{name: (owner, attribute, guarded function)}``: ``socket.socket.connect`` and
    ``connect_ex`` refuse (ConnectionRefusedError) an internet address that is not a loopback one, and
    ``socket.getaddrinfo`` refuses (socket.gaierror) to look up any other name (numeric addresses pass:
    nothing is sent to resolve them)."""

    def guard(real):
        def connect(sock, address, *args):
            if sock.family in (socket.AF_INET, socket.AF_INET6) and not is_loopback(address[0]):
                raise ConnectionRefusedError(111, f"the tests do not connect to {address[0]}")
            return real(sock, address, *args)
        return connect

    real_getaddrinfo = socket.getaddrinfo

    def getaddrinfo(host, *args, **kwargs):
        if not (is_loopback(host) or is_address(host)):      # a numeric address is no look-up (e.g. 0.0.0.0 to bind)
            raise socket.gaierror(socket.EAI_NONAME, f"the tests do not look up {host}")
        return real_getaddrinfo(host, *args, **kwargs)

    return {"connect": (socket.socket, "connect", guard(socket.socket.connect)),
            "connect_ex": (socket.socket, "connect_ex", guard(socket.socket.connect_ex)),
            "getaddrinfo": (socket, "getaddrinfo", getaddrinfo)}


if __name__ == "sitecustomize":           # imported by Python at start-up: guard this whole process
    for _owner, _attribute, _function in guarded().values():
        setattr(_owner, _attribute, _function)
