"""Headless Chromium driven over its DevTools protocol (a websocket, through aiohttp, which DVC brings).

For the browser tests (tests/test_dvc_plots_offline.py, tests/test_mlflow_ui_browser.py). Needs Chromium
from Debian's packages (``apt-get install chromium``); ``CHROMIUM`` is None without it.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import shutil
import signal
import subprocess
import time
from collections.abc import AsyncIterator
from pathlib import Path

CHROMIUM = next((shutil.which(name) for name in ("chromium", "chromium-browser", "google-chrome")
                 if shutil.which(name)), None)
FLAGS = ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--disable-quic",
         "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync"]
OFFLINE_FLAGS = ["--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE localhost, EXCLUDE 127.0.0.1",
                 "--proxy-server=http://127.0.0.1:9", "--proxy-bypass-list=<-loopback>"]
"""No name resolves, and anything else goes to a proxy where nothing listens: no network but loopback."""


class Page:
    """One page target: ``call`` a DevTools method, ``evaluate`` JavaScript; events land in ``events``."""

    def __init__(self, socket_, deadline: float):
        self._socket, self.deadline, self.events = socket_, deadline, []
        self._ids = iter(range(1, 10**9))

    async def call(self, method: str, **params) -> dict:
        number = next(self._ids)
        await self._socket.send_json({"id": number, "method": method, "params": params})
        async for message in self._socket:
            data = message.json()
            if data.get("id") == number:
                if "error" in data:
                    raise AssertionError(f"{method}: {data['error']}")
                return data.get("result", {})
            if "method" in data:
                self.events.append(data)
        raise AssertionError("DevTools connection closed")

    async def evaluate(self, expression: str, await_promise: bool = False):
        result = await self.call("Runtime.evaluate", expression=expression, returnByValue=True,
                                 awaitPromise=await_promise)
        if "exceptionDetails" in result:
            raise AssertionError(f"JavaScript failed: {result['exceptionDetails']}")
        return result.get("result", {}).get("value")

    async def wait_for(self, expression: str, what: str, poll_s: float = 0.5) -> None:
        while not await self.evaluate(expression):
            assert time.monotonic() < self.deadline, f"timed out waiting for {what}"
            await asyncio.sleep(poll_s)


@contextlib.asynccontextmanager
async def chromium_page(profile: Path, deadline_s: float, offline: bool = False,
                        window: str = "1800,700") -> AsyncIterator[Page]:
    """A fresh headless Chromium (its own empty profile in ``profile``) on about:blank; with ``offline``,
    its network is cut off (``OFFLINE_FLAGS``) but for loopback."""
    import aiohttp

    assert CHROMIUM, "no Chromium"
    profile.mkdir(parents=True, exist_ok=True)
    chromium = subprocess.Popen(
        [CHROMIUM, *FLAGS, *(OFFLINE_FLAGS if offline else []), f"--user-data-dir={profile}",
         f"--window-size={window}", "--remote-debugging-port=0", "about:blank"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + deadline_s
    try:
        port_file = profile / "DevToolsActivePort"
        while not port_file.exists() or not port_file.read_text().strip():
            assert time.monotonic() < deadline and chromium.poll() is None, "Chromium did not start"
            time.sleep(0.2)
        port = int(port_file.read_text().split()[0])
        async with aiohttp.ClientSession() as session:
            async with session.get(f"http://127.0.0.1:{port}/json") as response:
                target = next(t for t in await response.json() if t["type"] == "page")
            async with session.ws_connect(target["webSocketDebuggerUrl"], max_msg_size=0) as socket_:
                yield Page(socket_, deadline)
    finally:
        os.killpg(chromium.pid, signal.SIGKILL)
        chromium.wait(timeout=30)
