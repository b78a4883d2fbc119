"""One progress reporter for fits, posteriors and sweeps: a line on stderr
redrawn in place (no extra dependency)."""

from __future__ import annotations

import contextlib
import math
import sys
import threading
import time


class Progress:
    """``label [######......] step 42/100 text (12.1 s)``, redrawn in place.

    With ``rate=True`` (sweeps) the line counts rows instead:
    ``[######......]  42%  420,000/1,000,000  12.1 s  34,700/s  ETA 17 s``.
    ``every`` is the least time between two redraws (the last one always
    shows)."""

    def __init__(self, total, label="", width=30, *, rate=False, every=0.0,
                 stream=None, start=0):  # fmt: skip
        self.total, self.label, self.width = total, label, width
        self.rate, self.every = rate, every
        self.start = start  # rows done before (a resumed sweep): not in the rate
        self.stream = sys.stderr if stream is None else stream
        self.t0 = time.perf_counter()
        self.last = -math.inf
        self.shown = 0  # length of the line on screen, to overwrite it whole
        self._ticker = None  # (thread, stop event) of a live status line
        self._lock = threading.Lock()

    def _write(self, line: str, end: str = ""):
        with self._lock:
            self.stream.write("\r" + line.ljust(self.shown) + end)
            self.stream.flush()
            self.shown = 0 if end else len(line)

    def _stop_ticker(self):
        if self._ticker is not None:
            thread, stop = self._ticker
            stop.set()
            thread.join()
            self._ticker = None

    def _bar(self, done) -> str:
        filled = int(round(self.width * min(done, self.total) / self.total))
        return "#" * filled + "." * (self.width - filled)

    def update(self, done, text=None, final=False):
        """Show ``done`` of ``total``; ``text`` after the count (fits: the
        cost, NUTS: the phase and its divergences)."""
        now = time.perf_counter()
        if not final and now - self.last < self.every:
            return
        self._stop_ticker()
        self.last = now
        dt = now - self.t0
        if self.rate:
            speed = (done - self.start) / dt if dt > 0 else 0.0
            eta = (self.total - done) / speed if speed > 0 else math.inf
            tail = "done" if final else (
                f"ETA {eta:.0f} s" if math.isfinite(eta) else "ETA ?")  # fmt: skip
            line = (
                f"[{self._bar(done)}] {100 * done / self.total:3.0f}%  "
                f"{done:,}/{self.total:,}  {dt:.1f} s  {speed:,.0f}/s  {tail}"
            )
        else:
            what = "" if text is None else f" {text}"
            line = f"{self.label} [{self._bar(done)}] step {done}/{self.total}{what}"
            line += f" ({dt:.1f} s)"
        self._write(line, "\n" if final else "")

    def close(self):
        self._stop_ticker()
        self.stream.write("\n")  # keep the last bar on screen
        self.stream.flush()
        self.shown = 0

    def message(self, text: str, end: str = "", live: bool = False):
        """A status line (what is happening before or after the steps).
        ``live``: its clock keeps running, redrawn every half second until the
        next line (a compilation shows no steps, and a frozen "(0.0 s)" looks
        like a hang)."""
        self._stop_ticker()

        def draw():
            dt = time.perf_counter() - self.t0
            self._write(f"{self.label}: {text} ({dt:.1f} s)", end)

        draw()
        if live and not end:
            stop = threading.Event()

            def tick():
                while not stop.wait(0.5):
                    draw()

            thread = threading.Thread(target=tick, daemon=True)
            thread.start()
            self._ticker = (thread, stop)

    @contextlib.contextmanager
    def live(self, text: str):
        """A live status line (`message` with ``live``) for the span of a
        ``with`` block: its clock stops at the first step shown, or when the
        block ends, an exception included (a clock must not keep writing over
        the error message)."""
        self.message(text, live=True)
        try:
            yield self
        except BaseException:
            # the error's message starts on a line of its own
            self._stop_ticker()
            self.stream.write("\n")
            self.stream.flush()
            self.shown = 0
            raise
        finally:
            self._stop_ticker()
