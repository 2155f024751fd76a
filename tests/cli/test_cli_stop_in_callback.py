"""A stop (SIGINT, SIGTERM) whose handler runs inside a callback is not lost.

Python runs a signal's handler in whatever the main thread is executing. When that is a
garbage-collection callback (JAX registers one) or a ``__del__``, the interpreter does not
propagate the handler's exception: it printed "Exception ignored in: <function
_xla_gc_callback ...>" with a traceback and the process ran on. Seen in CI (stop 50): a
``fit-batch --processes 2`` worker given SIGTERM by its stopped launcher printed the traceback
twice and ran until the launcher's SIGKILL. Here a gc callback sends the signal itself, so that
its handler runs inside the callback every time.
"""

import gc
import signal
import sys
import time

import pytest

from brdf_fit.cli._common import REDELIVER_S, Terminated, raise_terminated, stop_signals


def _collect_with_a_stop_in_a_callback(sig, collected: list | None = None) -> None:
    """One garbage collection whose callback raises ``sig`` (its handler runs there), then a
    wait of many redelivery delays in ordinary code; ``collected`` gets the time the collection
    ended (a full collection in a long-running pytest worker took 1.7-2.1 s)."""
    fired = []

    def callback(phase, info):
        if phase == "start" and not fired:
            fired.append(True)
            signal.raise_signal(sig)  # the handler runs now, inside the callback

    gc.callbacks.append(callback)
    try:
        gc.collect()
        if collected is not None:
            collected.append(time.monotonic())
        assert fired
        time.sleep(50 * REDELIVER_S)  # the stop, raised again, ends this wait
    finally:
        gc.callbacks.remove(callback)


@pytest.fixture
def sigint_raises():
    """SIGINT as at a terminal (a suite started in the background has it ignored)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.mark.parametrize("sig, stop", [(signal.SIGTERM, Terminated),
                                       (signal.SIGINT, KeyboardInterrupt)])
def test_a_stop_in_a_gc_callback_is_raised_again(sigint_raises, sig, stop):
    seen = []
    alarm = signal.getsignal(signal.SIGALRM)
    hook = sys.unraisablehook
    sys.unraisablehook = seen.append  # whatever the command's hook passes on
    collected = []
    try:
        with pytest.raises(stop):
            with stop_signals():
                _collect_with_a_stop_in_a_callback(sig, collected)
        # from the end of the collection (0 if the stop came before the time was taken)
        waited = time.monotonic() - collected[0] if collected else 0.0
    finally:
        sys.unraisablehook = hook
    assert seen == []  # nothing printed as "Exception ignored"
    assert waited < 40 * REDELIVER_S  # raised again, not at the end of the wait
    assert signal.getsignal(signal.SIGALRM) == alarm  # the timer's handler removed


def test_negative_control_without_it_the_stop_is_lost(sigint_raises):
    """The same callback with only a raising SIGTERM handler, as commands had before: the
    exception goes to the unraisable hook (printed, in a program) and the work runs on."""
    seen = []
    hook = sys.unraisablehook
    previous = signal.signal(signal.SIGTERM, raise_terminated)
    sys.unraisablehook = seen.append
    try:
        _collect_with_a_stop_in_a_callback(signal.SIGTERM)  # returns: nothing stopped it
    finally:
        sys.unraisablehook = hook
        signal.signal(signal.SIGTERM, previous)
    assert [u.exc_type for u in seen] == [Terminated]
