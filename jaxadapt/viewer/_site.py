"""What every page jaxadapt serves shares: the address it binds, the
token a non-loopback address requires, the guard against other hosts
(DNS rebinding) and other origins, the page's assets and the URLs to
print. ``jaxadapt view``'s :class:`~jaxadapt.viewer._server.Server` and
``jaxadapt experiment``'s server are sites."""

import asyncio
import hmac
import importlib.resources
import logging

from jaxadapt.viewer._addresses import bracketed, is_wildcard, machine_names, split_authority


class Site:
    """A web application on ``host:port``.

    Parameters
    ----------
    name : str
        The command, named in refusals (``"jaxadapt view"``).
    host : str
        Address to bind; a non-loopback one requires ``token`` in every URL.
    port : int
        Port (0: any free one).
    token : str or None
        Secret every request must carry as ``?token=``; None on loopback.
    package : str
        The package whose ``static/`` folder holds the assets.
    assets : dict
        Route to ``(file name, content type)``, served from ``package``'s
        ``static/`` (never from a request's path).
    public : frozenset
        Routes served without the token: scripts, the same for everyone
        and holding no secret.
    """

    def __init__(self, name, host, port, token, package, assets, public=frozenset()):
        self.name, self.host, self.port, self.token = name, host, port, token
        self.public, self.runner, self.loop = public, None, None
        self.assets = {
            route: (importlib.resources.files(package).joinpath("static", file).read_bytes(), t)
            for route, (file, t) in assets.items()
        }

    def web_app(self, max_message):
        """An aiohttp application with the guard and the assets' routes."""
        from aiohttp import web  # (imported when served: `import jaxadapt` stays light)

        guard = web.middleware(lambda request, handler: self._guard(request, handler))
        app = web.Application(middlewares=[guard], client_max_size=max_message)
        for route in self.assets:
            app.router.add_get(route, self._asset)
        return app

    async def bind(self, app):
        """Serve ``app`` on the address; the port chosen when it was 0."""
        from aiohttp import web

        self.loop = asyncio.get_running_loop()
        self.runner = web.AppRunner(app, access_log=None, handle_signals=False, logger=_logger())
        await self.runner.setup()
        try:
            await web.TCPSite(self.runner, self.host, self.port).start()
        except BaseException:
            await self.runner.cleanup()
            raise
        self.port = self.runner.addresses[0][1]

    def urls(self):
        """The page's URLs, the first to print: bound to a wildcard address
        (``0.0.0.0``, ``::``, ``""``), the machine's name and its addresses
        (a wildcard address is no place a browser can go), then loopback's;
        otherwise the one address bound."""
        query = f"?token={self.token}" if self.token else ""
        hosts = machine_names(self.host) if is_wildcard(self.host) else [self.host]
        return [f"http://{bracketed(h)}:{self.port}/{query}" for h in hosts]

    async def _guard(self, request, handler):
        """Refuse requests without the token, for another host (DNS
        rebinding) or from another origin's page."""
        from aiohttp import web

        given = request.query.get("token", "").encode()
        public = request.path in self.public
        if self.token and not public and not hmac.compare_digest(given, self.token.encode()):
            return web.Response(status=403, text=f"{self.name}: missing or wrong token\n")
        host = request.headers.get("Host", "")
        if not self.token and not self._is_own(host):
            expected = " or ".join(f"{n}:{self.port}" for n in self._names())
            return web.Response(
                status=403,
                text=f"{self.name}: Host: expected {expected}, got {host!r}\n",
            )
        origin = request.headers.get("Origin")
        if origin is not None and not (
            origin.startswith("http://") and self._is_own(origin[7:], host)
        ):
            return web.Response(status=403, text=f"{self.name}: refused Origin {origin!r}\n")
        return await handler(request)

    def _names(self):
        """The names of this server without a token: loopback's and its address."""
        return list(dict.fromkeys(["127.0.0.1", "localhost", "[::1]", bracketed(self.host)]))

    def _is_own(self, authority, host=None):
        """Whether ``authority`` (a Host header, or an Origin's ``host[:port]``)
        names this server: one of :meth:`_names` (with a token, also the
        request's ``host``: any name of the machine, the token guards) and
        its port, which a browser leaves out for port 80."""
        names = self._names()
        if self.token and host:
            names.append(split_authority(host)[0])
        name, port = split_authority(authority)
        return name is not None and name in names and port == self.port

    async def _asset(self, request):
        from aiohttp import web

        body, content_type = self.assets[request.path]
        return web.Response(body=body, content_type=content_type)


class _ClientErrors(logging.Filter):
    """Drops aiohttp's report of a request it could not parse (no Host, a
    bad header line): the client gets a 400 saying so, and the terminal
    no traceback."""

    def filter(self, record):
        from aiohttp.http_exceptions import HttpProcessingError

        error = record.exc_info[1] if record.exc_info else None
        return not isinstance(error, HttpProcessingError)


def _logger():
    logger = logging.getLogger("jaxadapt.viewer.http")
    if not logger.filters:
        logger.addFilter(_ClientErrors())
    return logger
