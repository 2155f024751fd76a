"""Progress on stderr: a bar rewritten in place on a terminal, plain lines in a log."""

from __future__ import annotations

import sys


class Progress:
    """One status line on stderr (rewritten in place on a terminal, plain lines otherwise)."""

    def __init__(self, total: int, enabled: bool = True):
        self.total, self.done, self.enabled = total, 0, enabled
        self.tty = sys.stderr.isatty()

    def __call__(self, model: str, check: str) -> None:
        if not self.enabled:
            return
        self.done += 1
        self.show(self.done - 1, self.done, self.total, f"{model}: {check}")

    def show(self, filled_count: int, done: int, total: int, text: str) -> None:
        """Write ``[bar] done/total text``, the bar filled to ``filled_count / total``."""
        width = 24
        filled = int(width * filled_count / max(total, 1))
        msg = f"[{'#' * filled}{'-' * (width - filled)}] {done}/{total} {text}"
        if self.tty:
            print("\r" + msg.ljust(78), end="", file=sys.stderr, flush=True)
        else:
            print(msg, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.enabled and self.tty:
            print("\r" + " " * 78 + "\r", end="", file=sys.stderr, flush=True)


class StepProgress(Progress):
    """The steps of a chunked fit (``fit(progress=...)``) on stderr: the stage, the step and
    the loss, one line per step (rewritten in place on a terminal)."""

    def __init__(self, n_samples: int, enabled: bool = True):
        super().__init__(0, enabled)
        self.n_samples = n_samples

    def __call__(self, stage: str, step: int, loss: float) -> None:
        if not self.enabled:
            return
        where = ("a random subset" if stage == "coarse"
                 else f"all {self.n_samples:,} samples")
        msg = f"  step {step} on {where}: loss {loss:.6g}"
        if self.tty:
            print("\r" + msg.ljust(78), end="", file=sys.stderr, flush=True)
        else:
            print(msg, file=sys.stderr, flush=True)


class BatchProgress(Progress):
    """A bar of finished problems on stderr for fit_batch's ``progress`` callback."""

    def __init__(self, label: str, enabled: bool = True):
        super().__init__(0, enabled)
        self.label = label

    def __call__(self, done: int, total: int, stage: str) -> None:
        if self.enabled:
            self.show(done, done, total, f"{self.label}: {stage}")


def progress_callback(enabled: bool, label):
    """A status bar and the ``progress(done, total, *extra)`` callback the library calls;
    ``label`` is the text, or a function of the callback's extra arguments (e.g. the model)."""
    bar = Progress(0, enabled)

    def progress(done: int, total: int, *extra) -> None:
        if bar.enabled:
            bar.show(done, done, total, label(*extra) if callable(label) else label)

    return bar, progress
