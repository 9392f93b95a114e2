"""A headless Chromium as the viewer's client: connect to a viser server and take a screenshot.

viser renders in the browser (three.js, WebGL); a picture of the scene therefore needs a browser. The
screenshot is viser's own ``ClientHandle.get_render``: the server asks the connected page to render its
canvas and send the pixels back. Chromium runs headless with SwiftShader (software WebGL, no GPU, no
display). The browser is found as ``$PBDGRASP_CHROMIUM``, else ``chromium``, ``chromium-browser``,
``google-chrome`` on the PATH (Debian's package ``chromium``, which ``make test`` installs).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from assets.errors import InputError

__all__ = ["BrowserError", "find_chromium", "headless_client", "screenshot"]

CONNECT_TIMEOUT_S = 60.0
"""How long a started browser may take to open the page and connect [s] (SwiftShader is slow)."""
RENDER_TIMEOUT_S = 60.0


class BrowserError(InputError):
    """No usable browser, or the browser did not connect or render in time."""


def find_chromium() -> str:
    """The Chromium executable (see the module docstring). Raises :class:`BrowserError` if there is none."""
    env = os.environ.get("PBDGRASP_CHROMIUM")
    if env:
        found = shutil.which(env)
        if found is None:
            raise BrowserError(f"PBDGRASP_CHROMIUM={env} is not an executable")
        return found
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    raise BrowserError(
        "--screenshot needs Chromium: install Debian's package chromium (sudo apt-get install chromium) "
        "or set PBDGRASP_CHROMIUM"
    )


@contextmanager
def headless_client(server, width: int, height: int, timeout_s: float = CONNECT_TIMEOUT_S):
    """Start a headless Chromium on the server's page and yield its viser ``ClientHandle``.

    The browser and its temporary profile are removed on exit.

    Raises:
        BrowserError: no browser, or no connection within ``timeout_s``.
    """
    exe = find_chromium()
    connected = threading.Event()
    clients = []

    def on_connect(client) -> None:
        clients.append(client)
        connected.set()

    server.on_client_connect(on_connect)
    url = f"http://127.0.0.1:{server.get_port()}"
    with tempfile.TemporaryDirectory(prefix="pbdgrasp-chromium-", ignore_cleanup_errors=True) as profile:
        args = [
            exe,
            "--headless=new",
            "--no-sandbox",  # root in containers; the page is our own server on loopback
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--no-first-run",
            "--no-default-browser-check",
            "--disable-extensions",
            f"--user-data-dir={profile}",
            f"--window-size={width},{height}",
            url,
        ]
        proc = subprocess.Popen(
            args,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,  # its own process group: the renderer and GPU processes end with it
        )
        try:
            if not connected.wait(timeout_s):
                status = proc.poll()
                why = f"it exited with status {status}" if status is not None else "it did not connect"
                raise BrowserError(
                    f"headless {Path(exe).name} did not open {url} within {timeout_s:.0f} s: {why}"
                )
            yield clients[0]
        finally:
            _stop_group(proc)


def _stop_group(proc: subprocess.Popen) -> None:
    """End the browser and every process of its group (renderer, GPU) before its profile is removed."""
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(10)
    except (ProcessLookupError, subprocess.TimeoutExpired):
        pass
    try:
        os.killpg(proc.pid, signal.SIGKILL)  # what of the group is left
    except ProcessLookupError:
        pass
    proc.wait()


def screenshot(
    server, look, width: int = 1280, height: int = 800, timeout_s: float = RENDER_TIMEOUT_S
) -> np.ndarray:
    """One picture of the server's scene, (height, width, 3) uint8 RGB, on a white background.

    Args:
        server: a running ``viser.ViserServer``.
        look: ``look(client)`` points the client's camera (e.g. :meth:`StrategyViewer.look_from`).

    Raises:
        BrowserError: no browser, no connection or no frame in time.
    """
    with headless_client(server, width, height) as client:
        look(client)
        client.flush()
        try:
            rgba = client.get_render(height, width, transport_format="png", timeout=timeout_s)
        except TimeoutError:
            raise BrowserError(f"the headless browser sent no frame within {timeout_s:.0f} s") from None
    rgba = np.asarray(rgba)
    alpha = rgba[..., 3:4].astype(float) / 255.0
    rgb = rgba[..., :3].astype(float) * alpha + 255.0 * (1.0 - alpha)
    return np.round(rgb).astype(np.uint8)
