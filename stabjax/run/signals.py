"""SIGTERM and SIGHUP handled like Ctrl-C (issue 22, item 11).

By default both kill Python without a word: a batch scheduler's ``scancel``, a closed terminal or
``kill PID`` would end a sweep with no message and no clean exit status. :func:`install` makes them
raise :class:`stabjax.errors.Interrupted` (a ``KeyboardInterrupt``) so every path that keeps the
finished chunks on Ctrl-C keeps them here too, and the command line exits with 128 + the signal.

Between :func:`hold` and :func:`release` (the sweep's chunk loop) the first such signal is held until the chunk
in flight is written (:func:`checkpoint`), so its work is kept; a second signal stops at once.
Ctrl-C keeps Python's own behaviour (an immediate ``KeyboardInterrupt``): a user at a terminal who
presses it wants the prompt back now.
"""
from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

from ..errors import Interrupted

SIGNALS = tuple(s for s in (getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None)) if s is not None)
_state = {"defer": 0, "pending": None, "raised": None}


def _handler(signum, frame):
    if _state["defer"] and _state["pending"] is None:
        _state["pending"] = signum  # the chunk in flight finishes and is written first
        return
    _state["pending"] = None
    _state["raised"] = Interrupted(signum)
    raise _state["raised"]


def install() -> dict:
    """Handle SIGTERM and SIGHUP like Ctrl-C (main thread only: elsewhere Python refuses handlers).
    Returns the previous handlers, for :func:`restore` (the command line restores them when it returns,
    so a program or test that calls :func:`stabjax.app.cli.main` in-process keeps its own)."""
    _state["raised"] = None
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {s: signal.signal(s, _handler) for s in SIGNALS}


def last_raised() -> Interrupted | None:
    """The :class:`Interrupted` raised since :func:`install`, if any: typer turns every
    ``KeyboardInterrupt`` into status 130, and the command line restores 128 + signal from this."""
    return _state["raised"]


def restore(previous: dict) -> None:
    for s, h in previous.items():
        signal.signal(s, h if h is not None else signal.SIG_DFL)
    _state["pending"] = None


def hold() -> None:
    """From now on SIGTERM/SIGHUP are held until the next :func:`checkpoint` (the sweep calls it after
    each chunk is written); pair with :func:`release`."""
    _state["defer"] += 1


def release() -> None:
    """End a :func:`hold` (a signal still held is raised by the next :func:`checkpoint`, or at once if
    another arrives)."""
    _state["defer"] = max(0, _state["defer"] - 1)


def checkpoint() -> None:
    """Raise :class:`Interrupted` if a signal was held since the last checkpoint."""
    s = _state["pending"]
    if s is not None:
        _state["pending"] = None
        _state["raised"] = Interrupted(s)
        raise _state["raised"]


TEST_HOOK = "_STABJAX_TEST_SIGNAL_IN_CHUNK"  # tests only: "K:DIR"


def wait_in_chunk(i: int) -> None:
    """Tests only (``$_STABJAX_TEST_SIGNAL_IN_CHUNK = "K:DIR"``): chunk K announces that it is in flight
    (the file ``DIR/chunk-K``) and waits, at most 120 s, until a SIGTERM/SIGHUP is held; so a test's
    signal lands inside a chunk whatever the machine's speed, not in the gap between two chunks."""
    hook = os.environ.get(TEST_HOOK)
    if not hook:
        return
    k, _, folder = hook.partition(":")
    if not k.strip().isdigit() or int(k) != i or not folder:
        return
    Path(folder, f"chunk-{i}").touch()
    deadline = time.monotonic() + 120
    while _state["pending"] is None and time.monotonic() < deadline:
        time.sleep(0.01)
