"""What a command says: its result on stdout, an error as one line."""


def _report(line):
    """Print a line of a command's result (what it wrote, the group test) on
    stdout, as Unix tools do: warnings, progress and errors go to stderr."""
    print(line, flush=True)


def _message(error):
    """The one line that says what went wrong (:func:`jaxadapt.operators.checks.error_message`)."""
    from jaxadapt.operators.checks import error_message

    return error_message(error)
