"""Runs of ``jaxadapt`` in the test's process, and the check of their
one-line errors, shared by the command line's tests."""

from jaxadapt.cli import main

#: A built-in scene's size and duration that render in a moment.
SMALL = ["--size", "48x32", "--duration", "0.3"]


def run(capsys, *argv):
    """``jaxadapt ARGV``: ``(status, stderr)``."""
    status = main(list(argv))
    return status, capsys.readouterr().err


def assert_one_line_error(status, err, *words):
    """A usage error: status 2 and one line ``jaxadapt: error: ...`` that
    holds each of ``words``."""
    assert status == 2
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("jaxadapt: error:"), err
    for w in words:
        assert w in lines[0]
