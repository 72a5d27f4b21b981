"""The names and addresses of the machine the viewer serves from: which a
browser can open, which a request may name, and which are loopback."""

import contextlib
import ipaddress
import socket


def split_authority(text):
    """``(name, port)`` of ``host[:port]`` (port 80, HTTP's, when left out;
    names lower case); ``(None, None)`` where it is no such thing."""
    name, colon, port = text.rpartition(":")
    if not colon or name.startswith("[") and not name.endswith("]"):  # no port; IPv6 [::1]
        name, port = text, "80"
    if not name or not port.isdigit() or not port.isascii():
        return None, None
    return name.lower(), int(port)


def bracketed(host):
    return f"[{host}]" if ":" in host else host


def is_wildcard(host):
    """Whether ``host`` means every address of the machine (``0.0.0.0``, ``::``, ``""``)."""
    if host in ("", None):
        return True
    try:
        return ipaddress.ip_address(host).is_unspecified
    except ValueError:
        return False


def machine_names(wildcard="0.0.0.0"):
    """Names a browser can reach a server bound to ``wildcard`` by: the
    machine's host name, its addresses (those of its name and that of its
    default route; IPv4 for ``0.0.0.0``, IPv6 for ``::``, both for ``""``),
    then loopback's address."""
    families = {"0.0.0.0": [socket.AF_INET], "::": [socket.AF_INET6]}.get(
        str(ipaddress.ip_address(wildcard)) if wildcard else "",
        [socket.AF_INET, socket.AF_INET6],
    )
    names = [socket.gethostname()]
    for family in families:
        found = []
        try:
            found += [a[4][0] for a in socket.getaddrinfo(names[0], None, family)]
        except OSError:  # a name that does not resolve
            pass
        with contextlib.suppress(OSError), socket.socket(family, socket.SOCK_DGRAM) as probe:
            probe.connect(("192.0.2.1" if family == socket.AF_INET else "2001:db8::1", 9))
            found.append(probe.getsockname()[0])  # (a datagram socket sends nothing on connect)
        names += [a for a in found if not ipaddress.ip_address(a.split("%")[0]).is_loopback]
    names += ["127.0.0.1" if socket.AF_INET in families else "::1"]
    return list(dict.fromkeys(names))


def is_loopback(host):
    """Whether ``host`` (an address or ``localhost``) is this machine only."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
