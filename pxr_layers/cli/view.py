"""`pxr-layers view PATH`: the layer inspector, a local web page over one render."""

from __future__ import annotations

import argparse
import logging

from ..errors import Terminated
from .render import nonempty_path, positive_int

HELP = "inspect a render in the browser: its layers, regraded live, its light paths, new layers"
DESCRIPTION = (
    "Open the layer inspector on PATH: an output folder (its path index and the products of that "
    "render), an .exr product (and the index it names), or a .pxlidx index (and the products beside "
    "it). Starts a local web server, prints its URL (with a random access token: anyone with the URL "
    "can use the page) and opens the browser. The page shows the beauty and every layer through the "
    "products' OCIO display (any of its views), regrades the layers live (gain, tint, colour "
    "temperature, mute, solo, masks picked from the Cryptomattes), manages the stack (rename, "
    "duplicate, reorder, group, delete, undo and redo), compares looks (wipe, side by side, "
    "snapshots, the raw beauty), warns of layers that count the same light twice, lists the light "
    "paths of a clicked pixel or a dragged region, makes new layers from the index (or suggests K "
    "of them that add up to the beauty), saves the stack as a USD recipe (NAME.usda), its EXR "
    "(NAME.exr), a Nuke script (NAME.nk) and its working state (NAME.view.json), and pushes grades "
    "of whole lights into the shot as a UsdLux override layer (NAME.lights.usda, NAME.shot.usda), "
    "all in PATH's folder. The working state is kept beside the render (TITLE.view.json) and "
    "restored when the page or the view is opened again. Only the files of that folder are "
    "served. Ctrl-C stops it. docs/inspector.md tells more."
)
log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", type=nonempty_path, metavar="PATH", help="an output folder, an .exr product or a .pxlidx")
    parser.add_argument("--host", default="127.0.0.1",
                        help="the address to listen on (default 127.0.0.1: this machine only; another "
                        "address lets anyone who can reach it and has the URL use the page)")
    parser.add_argument("--port", type=_port, default=0,
                        help="the port to listen on (default 0: a free one)")
    parser.add_argument("--no-browser", action="store_true", help="print the URL, do not open a browser")
    parser.add_argument("--threads", type=positive_int, metavar="N",
                        help="threads that read the index for layers with covariance conditions (default: "
                        "every core this process may use; the rest reads faster on one)")


def run(args: argparse.Namespace) -> int:
    from ..layers.extract import default_threads
    from ..view.server import is_loopback, serve
    from ..view.session import Session

    session = Session.open(args.path, threads=args.threads or default_threads())
    if not is_loopback(args.host):
        log.warning("listening on %s: the page is reachable from other machines (with the token)", args.host)

    def announce(url: str) -> None:
        print(url, flush=True)  # stdout's first line: what scripts and tests read
        log.info("serving %s at %s (Ctrl-C stops)", session.folder, url)

    try:
        serve(session, announce, host=args.host, port=args.port, open_browser=not args.no_browser)
    except KeyboardInterrupt as interrupt:
        if isinstance(interrupt, Terminated):
            raise
        log.info("stopped")
    return 0


def _port(text: str) -> int:
    value = int(text)
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be a port number 0..65535, got {text}")
    return value
