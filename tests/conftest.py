"""Settings every test folder shares."""

import signal


def pytest_configure(config):
    # A test run started in the background by a script (`cmd &`, nohup) inherits SIGINT ignored, and so
    # would every process it starts; the tests that interrupt a child need SIGINT at its default, as in
    # a terminal. A Python handler here is reset to the default in each child at exec.
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
