"""Waiting for a forked child in the fork-safety tests, bounded in time."""
import os
import time

import pytest


def exit_code_of(pid, hang_message, timeout=60.0):
    """The exit code of child ``pid``; kills it and fails the test with ``hang_message`` after ``timeout`` s."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            return os.waitstatus_to_exitcode(status)
        time.sleep(0.02)
    os.kill(pid, 9)
    os.waitpid(pid, 0)
    pytest.fail(hang_message)
