"""One progress reporter for fits, posteriors and sweeps: a line on stderr
redrawn in place (no extra dependency)."""

from __future__ import annotations

import math
import sys
import time


class Progress:
    """``label [######......] step 42/100 text (12.1 s)``, redrawn in place.

    With ``rate=True`` (sweeps) the line counts rows instead:
    ``[######......]  42%  420,000/1,000,000  12.1 s  34,700/s  ETA 17 s``.
    ``every`` is the least time between two redraws (the last one always
    shows)."""

    def __init__(self, total, label="", width=30, *, rate=False, every=0.0,
                 stream=None):  # fmt: skip
        self.total, self.label, self.width = total, label, width
        self.rate, self.every = rate, every
        self.stream = sys.stderr if stream is None else stream
        self.t0 = time.perf_counter()
        self.last = -math.inf
        self.shown = 0  # length of the line on screen, to overwrite it whole

    def _write(self, line: str, end: str = ""):
        self.stream.write("\r" + line.ljust(self.shown) + end)
        self.stream.flush()
        self.shown = 0 if end else len(line)

    def _bar(self, done) -> str:
        filled = int(round(self.width * min(done, self.total) / self.total))
        return "#" * filled + "." * (self.width - filled)

    def update(self, done, text=None, final=False):
        """Show ``done`` of ``total``; ``text`` after the count (fits: the
        cost, NUTS: the phase and its divergences)."""
        now = time.perf_counter()
        if not final and now - self.last < self.every:
            return
        self.last = now
        dt = now - self.t0
        if self.rate:
            speed = done / dt if dt > 0 else 0.0
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
        self.stream.write("\n")  # keep the last bar on screen
        self.stream.flush()
        self.shown = 0

    def message(self, text: str, end: str = ""):
        """A status line (what is happening before or after the steps)."""
        dt = time.perf_counter() - self.t0
        self._write(f"{self.label}: {text} ({dt:.1f} s)", end)
