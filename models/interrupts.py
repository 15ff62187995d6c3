"""Ctrl-C always stops a run, even where CasADi swallows the KeyboardInterrupt.

CasADi checks for interrupts inside its solvers and converts numpy arrays
through Python code that clears errors, so a KeyboardInterrupt raised there
comes back as a RuntimeError ("... KeyboardInterrupt"), as a SystemError
("returned a result with an exception set"), or not at all, and a run would
go on (and end with exit status 0) or record a solver failure that never
happened. Code that calls CasADi in a loop

- calls `watch()` once: it installs a SIGINT handler that counts the signal and
  then does what Python's default handler does, raise KeyboardInterrupt (only
  where Python's default handler is installed, and from the main thread);
- runs each short CasADi-heavy piece of work (an MPC step) inside
  `deferred()`: there a SIGINT is only counted, and raised as KeyboardInterrupt
  when the block ends, so no CasADi or numpy code sees it;
- calls `clear()` when a run starts and `check()` between pieces of work
  (raises KeyboardInterrupt if a counted SIGINT was never delivered);
- re-raises in every ``except Exception`` around a CasADi call:
  ``if is_interrupt(err): raise KeyboardInterrupt from err``.

A command that must stop as cleanly on SIGTERM (``kill``, a job scheduler)
calls `terminate_as_interrupt()`: SIGTERM then acts as a SIGINT (even where SIGINT
is ignored), and `terminated()` tells the exit status apart (143 instead of 130).
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

_received = 0
_handled = 0
_terminated = False


def _count(signum, frame) -> None:
    """SIGINT handler: count the signal only (inside `deferred`)."""
    global _received
    _received += 1


def _count_and_interrupt(signum, frame):
    """SIGINT handler of `watch`: count the signal, then raise KeyboardInterrupt as Python's own does."""
    _count(signum, frame)
    raise KeyboardInterrupt


def _in_main_thread() -> bool:
    """Whether this is the main thread, the only one that may install signal handlers."""
    return threading.current_thread() is threading.main_thread()


def watch() -> bool:
    """Count SIGINTs from now on (idempotent); True when they are counted.

    Only Python's default handler is replaced (by one that also raises
    KeyboardInterrupt), and only from the main thread; a handler the program
    installed itself is left alone.
    """
    current = signal.getsignal(signal.SIGINT)
    if current is signal.default_int_handler and _in_main_thread():
        signal.signal(signal.SIGINT, _count_and_interrupt)
        return True
    return current in (_count_and_interrupt, _count)


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Within the block a SIGINT is counted, not raised; leaving the block raises KeyboardInterrupt
    if one arrived (also when the block raised: the interrupt wins).

    For short pieces of work only (an MPC step): the interrupt waits for the block to end. Where
    the program installed its own SIGINT handler, or outside the main thread, nothing changes.
    """
    previous = signal.getsignal(signal.SIGINT)
    if previous not in (signal.default_int_handler, _count_and_interrupt, _count) or not _in_main_thread():
        yield
        return
    signal.signal(signal.SIGINT, _count)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        check()


def clear() -> None:
    """Forget the SIGINTs counted so far (call when a run starts)."""
    global _handled
    _handled = _received


def pending() -> bool:
    """A counted SIGINT has not been delivered as a KeyboardInterrupt yet."""
    return _received > _handled


def received() -> int:
    """How many SIGINTs this process counted so far (never reset: `clear` only marks them delivered).

    A KeyboardInterrupt raised while Python runs a callback whose exceptions it ignores (a weakref
    callback, a module lock's) is lost; a command compares this count before and after its work to
    notice it.
    """
    return _received


def check() -> None:
    """Raise KeyboardInterrupt if a counted SIGINT was not delivered yet (and mark it delivered)."""
    if pending():
        clear()
        raise KeyboardInterrupt


def is_interrupt(err: BaseException) -> bool:
    """Whether `err` is an interrupt in disguise: a KeyboardInterrupt anywhere in its chain,
    CasADi's report of one, or any error while a counted SIGINT is pending.
    Marks the pending SIGINT delivered when it says True."""
    seen = set()
    chain: BaseException | None = err
    found = False
    while chain is not None and id(chain) not in seen:
        seen.add(id(chain))
        if isinstance(chain, KeyboardInterrupt) or "KeyboardInterrupt" in str(chain):
            found = True
            break
        chain = chain.__cause__ or chain.__context__
    found = found or pending()
    if found:
        clear()
    return found


def _terminate(signum, frame) -> None:
    """SIGTERM handler: remember it, then do what SIGINT's Python handler would (count, or raise).

    A process started in the background by a script (``cmd &``, nohup) has SIGINT ignored, so
    re-sending SIGINT would do nothing; without a Python SIGINT handler the interrupt is raised here.
    """
    global _terminated
    _terminated = True
    handler = signal.getsignal(signal.SIGINT)
    if callable(handler):
        handler(signal.SIGINT, frame)
    else:
        raise KeyboardInterrupt


def terminate_as_interrupt() -> bool:
    """Handle SIGTERM as a SIGINT from now on (main thread, where SIGTERM still has its default
    action); True when it does. `terminated()` says whether one arrived."""
    if _in_main_thread() and signal.getsignal(signal.SIGTERM) in (signal.SIG_DFL, _terminate):
        signal.signal(signal.SIGTERM, _terminate)
        return True
    return False


def terminated() -> bool:
    """Whether a SIGTERM arrived since `terminate_as_interrupt()` (the exit status is then 143)."""
    return _terminated
