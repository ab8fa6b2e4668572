"""The one exception the CLI turns into exit code 2.

Everything that is the user's fault (a bad scenario key, a malformed cube, a missing file) raises
:class:`BadInput` with a one-line message naming the file, the key path or dataset, the bad value and
what is allowed.  Anything else that escapes a command is an internal fault (exit 1, traceback kept).
"""


class BadInput(Exception):
    """Bad input: exit code 2, one plain line, no traceback."""

    def __init__(self, message: str):
        text = " ".join(str(message).split())  # always one line
        if len(text) > MAX_MESSAGE_CHARS:       # a safety net: values are cut where they are shown
            text = text[:700] + " [...] " + text[-250:]
        super().__init__(text)


MAX_MESSAGE_CHARS = 1000


class Terminated(BaseException):
    """SIGTERM received by a command (``cli``): raised in its main thread so that every ``finally`` and
    atomic writer runs (no ``.partial`` file left, no lock held), then exit code 143 (128 + SIGTERM)."""
