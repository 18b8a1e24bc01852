"""One headless Chromium for many pages, driven over the DevTools protocol on a pipe.

A Chromium launch costs 3.5-4.5 s of CPU (its software WebGL, SwiftShader, starting up), and so
does a page in a new renderer process; the replay's browser tests open about fifteen pages.
:class:`Chromium` launches the browser once (``--remote-debugging-pipe``: the protocol's JSON
messages, each ended by a NUL byte, on the child's file descriptors 3 (commands in) and 4 (replies
and events out)) and loads every page in one tab, each as a new document (the tab goes to
``about:blank`` in between), the way ``chromium --headless --window-size --screenshot --dump-dom
--virtual-time-budget`` does: the window sized, virtual time paused before the navigation and
then given the budget under the policy ``pauseIfNetworkFetchesPending``, the screenshot and the
DOM read once that budget has run out and the page has loaded.  (The pages share the tab's
storage, which the replay page does not use: meshcat's dat.gui writes ``localStorage`` only once
its "save locally" box is ticked.)

No dependency: the standard library's pipes and ``json``.
"""
from __future__ import annotations

import base64
import fcntl
import json
import os
import select
import signal
import subprocess
import time
from pathlib import Path

CHROMIUM = Path("/usr/bin/chromium")

# the flags the replay's one-shot launches used, less the per-page ones (the window size,
# --screenshot, --dump-dom, --virtual-time-budget, the URL): those are per page here
FLAGS = ("--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--disable-background-networking", "--no-first-run", "--disable-gpu-sandbox", "--hide-scrollbars")

# what --dump-dom prints (the doctype, then the document's outer HTML)
_DOM = ("(document.doctype ? new XMLSerializer().serializeToString(document.doctype) + '\\n' : '')"
        " + document.documentElement.outerHTML")


class ChromiumError(RuntimeError):
    """The browser died, answered a command with an error, or did not answer in time."""


class Chromium:
    """A headless Chromium kept running; :meth:`open` loads one page, screenshots it, reads its DOM.

    ``profile`` is a fresh directory for the browser's user data (and its log, ``chromium.log``).
    """

    def __init__(self, profile: Path, timeout: float = 150.0):
        self.timeout = timeout
        profile.mkdir(parents=True, exist_ok=True)
        self.log = profile / "chromium.log"
        to_child_r, self._to_child = os.pipe()
        self._from_child, from_child_w = os.pipe()

        def pipes_as_3_and_4():  # in the child, before exec: the protocol's fds
            r = fcntl.fcntl(to_child_r, fcntl.F_DUPFD, 5)  # above 3 and 4, so neither dup2 clobbers the other
            w = fcntl.fcntl(from_child_w, fcntl.F_DUPFD, 5)
            os.dup2(r, 3)
            os.dup2(w, 4)  # dup2 leaves 3 and 4 inheritable; every other pipe end closes at exec
            os.close(r)
            os.close(w)

        with open(self.log, "wb") as log:
            self.proc = subprocess.Popen(
                [str(CHROMIUM), *FLAGS, f"--user-data-dir={profile}", "--remote-debugging-pipe", "about:blank"],
                stdin=subprocess.DEVNULL, stdout=log, stderr=log, close_fds=False,
                preexec_fn=pipes_as_3_and_4, start_new_session=True)
        os.close(to_child_r)
        os.close(from_child_w)
        self._buffer = b""
        self._next_id = 0
        self._events: list[dict] = []
        self._session: str | None = None
        self._target: str | None = None
        self.call("Browser.getVersion")  # the browser is up and listening

    # ---- the protocol ---------------------------------------------------------------------
    def _message(self, deadline: float) -> dict:
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                raise ChromiumError(f"chromium did not answer in {self.timeout:g} s{self._log_tail()}")
            ready, _, _ = select.select([self._from_child], [], [], left)
            if ready:
                chunk = os.read(self._from_child, 1 << 20)
                if not chunk:
                    raise ChromiumError(f"chromium closed its DevTools pipe (exit {self.proc.poll()}){self._log_tail()}")
                self._buffer += chunk
        text, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(text)

    def call(self, method: str, session: str | None = None, **params) -> dict:
        """Send one command (to the browser, or to a page's ``session``) and return its result;
        events that arrive meanwhile are kept for :meth:`wait_for`."""
        self._next_id += 1
        msg = {"id": self._next_id, "method": method, "params": params}
        if session is not None:
            msg["sessionId"] = session
        data = json.dumps(msg).encode() + b"\0"
        while data:
            data = data[os.write(self._to_child, data):]
        deadline = time.monotonic() + self.timeout
        while True:
            reply = self._message(deadline)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise ChromiumError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            if "method" in reply:
                self._events.append(reply)

    def wait_for(self, session: str, *methods: str) -> None:
        """Wait until each of the events ``methods`` has arrived for ``session`` (in any order)."""
        deadline = time.monotonic() + self.timeout
        missing = set(methods)
        while True:
            for ev in [e for e in self._events if e.get("sessionId") == session and e["method"] in missing]:
                missing.discard(ev["method"])
            self._events = [e for e in self._events if e.get("sessionId") != session or e["method"] not in methods]
            if not missing:
                return
            reply = self._message(deadline)
            if "method" in reply:
                self._events.append(reply)

    # ---- a page ----------------------------------------------------------------------------
    def _tab(self) -> str:
        """The session of the one tab every page is loaded in (opened on first use)."""
        if self._session is None:
            target = self.call("Target.createTarget", url="about:blank")["targetId"]
            self._session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
            self._target = target
            self.call("Page.enable", self._session)
        return self._session

    def _load(self, url: str, size: tuple[int, int], virtual_time_budget_ms: int) -> str:
        """Load ``url`` afresh in the tab, in a window of ``size``, and let it run for the
        budget of virtual time; returns the tab's session."""
        width, height = size
        tab = self._tab()
        # a new document every time, also when only the URL's fragment (#t=...) differs
        self._forget(tab)
        self.call("Page.navigate", tab, url="about:blank")
        self.wait_for(tab, "Page.loadEventFired")
        window = self.call("Browser.getWindowForTarget", targetId=self._target)["windowId"]
        self.call("Browser.setWindowBounds", windowId=window, bounds={"width": width, "height": height})
        self.call("Emulation.setDeviceMetricsOverride", tab, width=width, height=height,
                  deviceScaleFactor=1, mobile=False)
        # virtual time stands still until the page is navigated, then runs for the budget
        self.call("Emulation.setVirtualTimePolicy", tab, policy="pause")
        self._forget(tab)
        nav = self.call("Page.navigate", tab, url=url)
        if "errorText" in nav:
            raise ChromiumError(f"{url}: {nav['errorText']}")
        self.call("Emulation.setVirtualTimePolicy", tab, policy="pauseIfNetworkFetchesPending",
                  budget=virtual_time_budget_ms)
        self.wait_for(tab, "Page.loadEventFired", "Emulation.virtualTimeBudgetExpired")
        return tab

    def _screenshot(self, tab: str, path: Path) -> None:
        png = self.call("Page.captureScreenshot", tab, format="png")["data"]
        path.write_bytes(base64.b64decode(png))

    def _park(self, tab: str) -> None:
        # park the tab: a replay page left loaded keeps its WebGL scene rendering in the GPU
        # process (measured: 0.9 of a core while the browser waits for the next test, 0.06 on
        # about:blank), which slowed every other test of the suite
        self._forget(tab)
        self.call("Page.navigate", tab, url="about:blank")
        self.wait_for(tab, "Page.loadEventFired")

    def open(self, url: str, size: tuple[int, int] = (800, 600), screenshot: Path | None = None,
             dom: bool = False, virtual_time_budget_ms: int = 3000) -> str | None:
        """Load ``url`` afresh in a window of ``size`` (width, height) pixels, let its scripts run
        for ``virtual_time_budget_ms`` of virtual time, then write a PNG of the window into
        ``screenshot`` and/or return the DOM (``dom``)."""
        try:
            tab = self._load(url, size, virtual_time_budget_ms)
            text = None
            if screenshot is not None:
                self._screenshot(tab, screenshot)
            if dom:
                text = self.call("Runtime.evaluate", tab, expression=_DOM, returnByValue=True)["result"]["value"]
            self._park(tab)
            return text
        except BaseException:
            self._drop_tab()  # the next page gets a new tab, whatever state this one was left in
            raise

    def shots(self, url: str, size: tuple[int, int], steps: list[tuple[str | None, Path]],
              virtual_time_budget_ms: int = 3000, step_budget_ms: int = 500, dom_step: int | None = None) -> str | None:
        """Load ``url`` once as :meth:`open` does; then for each ``(expression, screenshot)`` of
        ``steps``: evaluate the JavaScript ``expression`` in the page (none: the page as loaded),
        let it run for ``step_budget_ms`` of virtual time (its animation frames draw what the
        expression changed) and write a PNG of the window into ``screenshot``.  Returns the DOM
        as it is at step ``dom_step`` (if given)."""
        text = None
        try:
            tab = self._load(url, size, virtual_time_budget_ms)
            for i, (expression, screenshot) in enumerate(steps):
                if expression is not None:
                    reply = self.call("Runtime.evaluate", tab, expression=expression)
                    if "exceptionDetails" in reply:
                        raise ChromiumError(f"{expression}: {reply['exceptionDetails']}")
                    self._forget(tab)
                    self.call("Emulation.setVirtualTimePolicy", tab, policy="pauseIfNetworkFetchesPending",
                              budget=step_budget_ms)
                    self.wait_for(tab, "Emulation.virtualTimeBudgetExpired")
                self._screenshot(tab, screenshot)
                if i == dom_step:
                    text = self.call("Runtime.evaluate", tab, expression=_DOM, returnByValue=True)["result"]["value"]
            self._park(tab)
            return text
        except BaseException:
            self._drop_tab()
            raise

    def _forget(self, session: str) -> None:
        """Drop the events kept for ``session``: what :meth:`wait_for` waits for next is new."""
        self._events = [e for e in self._events if e.get("sessionId") != session]

    def _drop_tab(self) -> None:
        target, self._session, self._target = self._target, None, None
        if target is not None and self.proc.poll() is None:
            try:
                self.call("Target.closeTarget", targetId=target)
            except (ChromiumError, OSError):
                pass

    # ---- the end ---------------------------------------------------------------------------
    def close(self) -> None:
        """Ask the browser to close; kill it (and its children) if it has not within 10 s."""
        try:
            if self.proc.poll() is None:
                self.call("Browser.close")
        except (ChromiumError, OSError):
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            pass
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)  # chromium's renderer and GPU processes too
        except ProcessLookupError:
            pass
        self.proc.wait()
        for fd in (self._to_child, self._from_child):
            os.close(fd)

    def _log_tail(self) -> str:
        try:
            return "\nchromium's log ends:\n" + self.log.read_text(errors="replace")[-2000:]
        except OSError:
            return ""
