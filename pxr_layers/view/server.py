"""The inspector's local HTTP server (aiohttp): the page, its API over one :class:`Session`,
and the files of the session's folder. The API is written down in docs/inspector-api.md.

Security, as Jupyter does it: the server binds 127.0.0.1 unless told otherwise; every
request carries a random token (``?token=`` in the URL the command prints, then the
``X-Pxr-Token`` header; requests that change anything take the header only, which a page
of another site cannot set); a request naming another host is refused (DNS rebinding); the
only files served are the page's own and the regular files inside the session's folder.
"""

from __future__ import annotations

import asyncio
import errno
import functools
import hmac
import json
import logging
import math
import secrets
import socket
import webbrowser
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from importlib import resources
from pathlib import Path, PurePosixPath

from aiohttp import web

from ..errors import PxrLayersError
from .session import LUT_URL, Session, ViewError

log = logging.getLogger(__name__)

TOKEN_HEADER = "X-Pxr-Token"
TOKEN_PLACEHOLDER = "{{TOKEN}}"
"""Replaced by the token in index.html, so the page's own assets carry it."""
LOOPBACK = ("127.0.0.1", "localhost", "::1")
"""The names of this machine the server answers to when it listens on one of them."""
MAX_BODY_BYTES = 1 << 20
MAX_BODY_DEPTH = 32
"""Deepest nesting of arrays and objects a JSON body may have (the API needs 3)."""
MAX_PATH_CHARS = 1024
"""Longest relative path /files/ looks up (a file name longer than the system's is a 404)."""
REQUEST_ERRORS = (ValueError, UnicodeError, RecursionError, OverflowError)
"""Exceptions a malformed request raises: a 400, not a bug."""
SESSION_KEY = web.AppKey("session", Session)
POOL_KEY = web.AppKey("pool", ThreadPoolExecutor)


def static_files() -> dict[str, Path]:
    """The page's files (pxr_layers/view/static), by name: nothing else is served from there."""
    folder = resources.files("pxr_layers.view").joinpath("static")
    return {entry.name: Path(str(entry)) for entry in folder.iterdir() if entry.is_file()}


def make_app(session: Session, token: str, allowed_hosts: frozenset[str] | None) -> web.Application:
    """The application. allowed_hosts: the Host headers accepted (None: any, when the user
    binds a non-loopback address on purpose)."""
    app = web.Application(middlewares=[_errors, _guard(token, allowed_hosts)], client_max_size=MAX_BODY_BYTES)
    app[SESSION_KEY] = session
    app[POOL_KEY] = ThreadPoolExecutor(2, thread_name_prefix="pxl-view")
    app.on_cleanup.append(_stop_pool)
    files = static_files()
    page = files["index.html"].read_text(encoding="utf-8").replace(TOKEN_PLACEHOLDER, token)

    async def index(request: web.Request) -> web.Response:
        return web.Response(text=page, content_type="text/html", headers={"Cache-Control": "no-store"})

    async def static(request: web.Request) -> web.StreamResponse:
        path = files.get(request.match_info["name"])
        if path is None or request.match_info["name"] == "index.html":
            raise web.HTTPNotFound()
        return web.FileResponse(path, headers={"Cache-Control": "no-store"})

    app.router.add_get("/", index)
    app.router.add_get("/static/{name}", static)
    app.router.add_get("/files/{name:.+}", _folder_file)
    app.router.add_get("/api/session", _session_description)
    app.router.add_get(LUT_URL, _lut)
    app.router.add_get("/api/display", _display)
    app.router.add_get("/api/image/{layer}", _image)
    app.router.add_get("/api/inspect", _inspect)
    app.router.add_get("/api/mask", _mask)
    app.router.add_get("/api/pick", _pick)
    app.router.add_post("/api/check", _check)
    app.router.add_post("/api/generalise", _generalise)
    app.router.add_post("/api/layer", _layer)
    app.router.add_post("/api/suggest", _suggest)
    app.router.add_post("/api/overlaps", _overlaps)
    app.router.add_post("/api/save", _save)
    app.router.add_post("/api/push", _push)
    app.router.add_post("/api/pushable", _pushable)
    app.router.add_put("/api/document", _document)
    return app


def _guard(token: str, allowed_hosts: frozenset[str] | None):
    @web.middleware
    async def guard(request: web.Request, handler):
        if allowed_hosts is not None and request.host not in allowed_hosts:
            return _error(f"host {request.host!r} is not this server", 403)
        given = request.headers.get(TOKEN_HEADER)
        if given is None and request.method in ("GET", "HEAD"):
            given = request.query.get("token")
        if given is None or not hmac.compare_digest(given.encode("utf-8", "surrogateescape"), token.encode()):
            return _error("a valid access token is needed (open the URL `pxr-layers view` printed)", 403)
        return await handler(request)

    return guard


@web.middleware
async def _errors(request: web.Request, handler):
    try:
        return await handler(request)
    except web.HTTPException:
        raise
    except ViewError as error:
        return _error(str(error), error.status, error.position)
    except PxrLayersError as error:
        return _error(_one_line(error), 400)
    except REQUEST_ERRORS as error:  # raised by what the request carried: say so, keep serving
        log.info("bad request %s: %r", request.path, error)
        return _error(f"bad request: {_one_line(error) or type(error).__name__}", 400)
    except OSError as error:
        if error.errno in (errno.ENAMETOOLONG, errno.ELOOP):
            return _error(f"bad request: {error.strerror}", 400)
        log.exception("internal error serving %s", request.path)
        return _error("internal error (the server's log has the details)", 500)
    except Exception:  # a bug: logged whole, one line to the page
        log.exception("internal error serving %s", request.path)
        return _error("internal error (the server's log has the details)", 500)


def _one_line(error: Exception) -> str:
    lines = str(error).splitlines()
    return lines[0][:500] if lines else ""


def _error(message: str, status: int, position: int | None = None) -> web.Response:
    body = {"error": message} if position is None else {"error": message, "position": position}
    return web.json_response(body, status=status)


async def _stop_pool(app: web.Application) -> None:
    app[POOL_KEY].shutdown(wait=False, cancel_futures=True)


async def _blocking(request: web.Request, function: Callable, *args):
    """Run session work (index reads, extraction, file writes) off the event loop."""
    loop = asyncio.get_running_loop()
    return await loop.run_in_executor(request.app[POOL_KEY], functools.partial(function, *args))


def _json_depth(data: bytes) -> int:
    """The deepest nesting of arrays and objects in `data` (brackets inside strings skipped),
    counted before parsing: json.loads recurses once a level."""
    depth = deepest = 0
    in_string = escaped = False
    for byte in data:
        if in_string:
            if escaped:
                escaped = False
            elif byte == 0x5C:  # backslash
                escaped = True
            elif byte == 0x22:
                in_string = False
        elif byte == 0x22:
            in_string = True
        elif byte in (0x5B, 0x7B):
            depth += 1
            if depth > deepest:
                deepest = depth
                if deepest > MAX_BODY_DEPTH:
                    break
        elif byte in (0x5D, 0x7D):
            depth -= 1
    return deepest


def _no_constant(name: str):
    raise ValueError(f"{name} is not a number JSON allows")


def _finite(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"{text[:40]} is too large a number")
    return value


async def _json_body(request: web.Request) -> dict:
    data = await request.read()  # past client_max_size: 413
    if _json_depth(data) > MAX_BODY_DEPTH:
        raise ViewError(f"the request body nests deeper than {MAX_BODY_DEPTH} levels")
    try:
        body = json.loads(data.decode("utf-8"), parse_constant=_no_constant, parse_float=_finite)
    except (ValueError, UnicodeDecodeError, RecursionError):  # JSONDecodeError is a ValueError; so are huge ints
        raise ViewError("the request body is not JSON") from None
    if not isinstance(body, dict):
        raise ViewError("the request body is not a JSON object")
    return body


# --- handlers -------------------------------------------------------------------------------


async def _session_description(request: web.Request) -> web.Response:
    return web.json_response(request.app[SESSION_KEY].description())


async def _lut(request: web.Request) -> web.Response:
    pixels = await _blocking(request, request.app[SESSION_KEY].lut_pixels, request.query.get("view"))
    return web.Response(body=pixels, content_type="application/octet-stream")


async def _display(request: web.Request) -> web.Response:
    description = await _blocking(request, request.app[SESSION_KEY].display_description, request.query.get("view"))
    return web.json_response(description)


async def _image(request: web.Request) -> web.Response:
    session = request.app[SESSION_KEY]
    layer = session.layer(request.match_info["layer"])
    return web.Response(body=layer.pixels(request.query.get("version", "raw")), content_type="application/octet-stream",
                        headers={"X-Width": str(session.width), "X-Height": str(session.height),
                                 "Cache-Control": "no-store"})


async def _inspect(request: web.Request) -> web.Response:
    try:
        x0, y0, x1, y1 = (int(request.query[key]) for key in ("x0", "y0", "x1", "y1"))
    except (KeyError, ValueError):
        raise ViewError("inspect needs integer x0, y0, x1, y1 (pixels, x1 and y1 exclusive)") from None
    return web.json_response(await _blocking(request, request.app[SESSION_KEY].inspect, x0, y0, x1, y1))


async def _mask(request: web.Request) -> web.Response:
    """The coverage of ``names`` (a JSON array, or ``names=`` repeated) in the ``kind``'s Cryptomatte."""
    session = request.app[SESSION_KEY]
    names = request.query.getall("names", [])
    if len(names) == 1 and names[0].lstrip().startswith("["):
        try:
            names = json.loads(names[0], parse_constant=_no_constant)
        except (ValueError, RecursionError):
            raise ViewError("names is a JSON array of names, or names= repeated") from None
    pixels = await _blocking(request, session.mask, request.query.get("kind"), names)
    return web.Response(body=pixels, content_type="application/octet-stream",
                        headers={"X-Width": str(session.width), "X-Height": str(session.height)})


async def _pick(request: web.Request) -> web.Response:
    try:
        x, y = (int(request.query[key]) for key in ("x", "y"))
    except (KeyError, ValueError):
        raise ViewError("pick needs integer x, y (a pixel: x from the left, y from the top)") from None
    return web.json_response(request.app[SESSION_KEY].pick(x, y))


async def _check(request: web.Request) -> web.Response:
    body = await _json_body(request)
    try:
        request.app[SESSION_KEY].check(body.get("expression"))
    except ViewError as error:
        return web.json_response({"ok": False, "error": str(error), "position": error.position})
    return web.json_response({"ok": True,
                              "unknown_labels": request.app[SESSION_KEY].unknown_labels(body.get("expression"))})


async def _generalise(request: web.Request) -> web.Response:
    body = await _json_body(request)
    session = request.app[SESSION_KEY]
    return web.json_response({"lpe": session.generalise(body.get("classes"), body.get("keep") or [])})


async def _layer(request: web.Request) -> web.Response:
    body = await _json_body(request)
    session = request.app[SESSION_KEY]
    layer, facts = await _blocking(request, session.add_layer, body.get("name"), body.get("expression"))
    return web.json_response({**layer.description(), **facts,
                              "unknown_labels": session.unknown_labels(layer.expression)})


async def _overlaps(request: web.Request) -> web.Response:
    body = await _json_body(request)
    return web.json_response(await _blocking(request, request.app[SESSION_KEY].overlaps, body.get("layers")))


async def _suggest(request: web.Request) -> web.Response:
    body = await _json_body(request)
    layers, facts = await _blocking(request, request.app[SESSION_KEY].suggest_layers, body.get("k"), body.get("exclude"))
    return web.json_response({"layers": [layer.description() for layer in layers], **facts})


async def _save(request: web.Request) -> web.Response:
    body = await _json_body(request)
    session = request.app[SESSION_KEY]
    overwrite = _overwrite(body)
    written = await _blocking(request, session.save, body.get("name"), body.get("layers"),
                              body.get("exposure", 0.0), overwrite, body.get("document"))
    return web.json_response(written)


async def _push(request: web.Request) -> web.Response:
    """/api/push writes the grades of whole lights as light overrides; /api/pushable says,
    without writing, which entries would push and why the others stay compositing grades."""
    body = await _json_body(request)
    overwrite = _overwrite(body)
    session = request.app[SESSION_KEY]
    return web.json_response(await _blocking(request, session.push, body.get("name"), body.get("layers"),
                                             body.get("exposure", 0.0), overwrite))


async def _pushable(request: web.Request) -> web.Response:
    body = await _json_body(request)
    return web.json_response(await _blocking(request, request.app[SESSION_KEY].pushable, body.get("layers")))
def _overwrite(body: dict) -> bool:
    """The body's "overwrite": a boolean (the page's overwrite box), false when left out."""
    overwrite = body.get("overwrite", False)
    if not isinstance(overwrite, bool):
        raise ViewError(f"overwrite must be true or false, not {overwrite!r}")
    return overwrite


async def _document(request: web.Request) -> web.Response:
    body = await _json_body(request)
    return web.json_response(await _blocking(request, request.app[SESSION_KEY].put_document, body))


async def _folder_file(request: web.Request) -> web.StreamResponse:
    """A regular file inside the session's folder, by its relative path: no absolute path,
    no ``..``, nothing a symbolic link takes outside the folder."""
    folder = request.app[SESSION_KEY].folder
    name = request.match_info["name"]
    relative = PurePosixPath(name)
    shown = repr(name[:80] + ("…" if len(name) > 80 else ""))
    if relative.is_absolute() or ".." in relative.parts or "\\" in name or "\x00" in name:
        return _error(f"{shown}: only files inside {folder.name}/ are served", 403)
    try:  # a loop of symbolic links, a name past the system's limit: no such file either
        if len(name) > MAX_PATH_CHARS:
            raise OSError(errno.ENAMETOOLONG, "name too long")
        path = (folder / relative).resolve()
        found = path.is_relative_to(folder) and path.is_file()
    except (OSError, RuntimeError, ValueError):  # RuntimeError: resolve() meeting a loop (Python < 3.13)
        found = False
    if not found:
        return _error(f"{shown}: no such file inside {folder.name}/", 404)
    return web.FileResponse(path)


# --- running ---------------------------------------------------------------------------------


def is_loopback(host: str) -> bool:
    return host in LOOPBACK


def serve(session: Session, announce: Callable[[str], None], *, host: str = "127.0.0.1", port: int = 0,
          open_browser: bool = True) -> None:
    """Serve `session` until interrupted. `announce` gets the URL (with its token) once the
    socket listens; port 0 takes a free one. Raises ViewError when the address cannot be had."""
    token = secrets.token_urlsafe(24)
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    listening = socket.socket(family, socket.SOCK_STREAM)
    listening.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        listening.bind((host, port))
    except OSError as error:
        listening.close()
        raise ViewError(f"cannot listen on {host}:{port} ({error.strerror or error})") from None
    port = listening.getsockname()[1]
    allowed = frozenset(f"[{name}]:{port}" if ":" in name else f"{name}:{port}" for name in LOOPBACK) \
        if is_loopback(host) else None  # another address is the user's choice: any name may reach it
    url = f"http://{'[' + host + ']' if ':' in host else host}:{port}/?token={token}"
    asyncio.run(_run(make_app(session, token, allowed), listening, url, open_browser, announce))


async def _run(app: web.Application, listening: socket.socket, url: str, open_browser: bool,
               announce: Callable[[str], None]) -> None:
    runner = web.AppRunner(app, access_log=None)
    await runner.setup()
    try:
        await web.SockSite(runner, listening).start()
        announce(url)
        if open_browser:
            await asyncio.get_running_loop().run_in_executor(None, webbrowser.open, url)
        await asyncio.Event().wait()  # until Ctrl-C or SIGTERM
    finally:
        await runner.cleanup()
