"""The loop process's own parts (app/backend/loop_process.py) that need no running loop;
the paced loop itself is exercised through the web app (tests/test_backend_*.py)."""

from __future__ import annotations

import multiprocessing

import pytest

from app.backend.loop_process import readable


def test_readable_answers_as_connection_poll_through_a_message_and_the_pipes_end():
    ours, theirs = multiprocessing.Pipe()
    ready = readable(theirs)
    assert ready() is False and theirs.poll() is False
    ours.send(("cmd", 1))
    ours.send(("stop",))
    assert ready() is True and theirs.poll() is True
    assert theirs.recv() == ("cmd", 1)
    assert ready() is True  # the second message still waits
    assert theirs.recv() == ("stop",)
    assert ready() is False and theirs.poll() is False
    ours.close()  # the web process went away: readable, and recv says so
    assert ready() is True and theirs.poll() is True
    with pytest.raises(EOFError):
        theirs.recv()
    theirs.close()
