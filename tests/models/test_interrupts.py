"""SIGTERM stops a run as Ctrl-C does, also where SIGINT is ignored."""

import signal
import subprocess
import sys
import textwrap

import pytest

CHILD = textwrap.dedent(
    """
    import signal, sys, time
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # as in a run started with `nohup cmd &`
    from models import interrupts
    assert interrupts.terminate_as_interrupt()
    try:
        print("ready", flush=True)  # inside the try: the signal may arrive as soon as it is out
        time.sleep(20)
    except KeyboardInterrupt:
        print("interrupted", interrupts.terminated(), flush=True)
        sys.exit(143)
    print("slept on", flush=True)
    """
)


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_sigterm_interrupts_a_process_whose_sigint_is_ignored():
    child = subprocess.Popen([sys.executable, "-c", CHILD], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert child.stdout.readline().strip() == "ready"
    child.send_signal(signal.SIGTERM)
    out, err = child.communicate(timeout=30)
    assert (child.returncode, out.strip()) == (143, "interrupted True"), err


LOST = textwrap.dedent(
    """
    import gc, os, signal, weakref
    from models import interrupts
    assert interrupts.watch()
    before = interrupts.received()

    class Thing:
        pass

    def callback(ref):  # Python ignores what a weakref callback raises ("Exception ignored in")
        os.kill(os.getpid(), signal.SIGINT)

    thing = Thing()
    ref = weakref.ref(thing, callback)
    del thing
    gc.collect()
    interrupts.clear()  # a later run's start forgets the pending one ...
    print(interrupts.pending(), interrupts.received() - before, flush=True)  # ... the count keeps it
    """
)


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_an_interrupt_python_ignored_in_a_callback_is_still_counted():
    done = subprocess.run([sys.executable, "-c", LOST], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "KeyboardInterrupt" in done.stderr  # the interrupt was raised, and swallowed
    assert done.stdout.split() == ["False", "1"]
