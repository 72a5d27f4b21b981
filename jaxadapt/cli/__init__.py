"""The command line: ``jaxadapt render``, ``jaxadapt psychometric fit`` and
``jaxadapt psychometric simulate``, one module per command.

Every error that comes from the user's input (arguments, files, values)
prints one line on stderr and exits with status 2. Outputs are written into
a staging folder inside ``--out`` and moved into place only when the whole
run has succeeded, so a failed run leaves nothing half-written and
overwrites nothing. A run that could read an input only in part (a video
file cut short) renders what it read, says so in a warning and exits with
status 3. An interrupted run (Ctrl-C, SIGTERM as a job
scheduler sends it, or SIGHUP as a closed terminal does) is a failed one: it
removes its staging folder, prints one line and exits with status 130 (143
for SIGTERM, 129 for SIGHUP), as a shell reports such a signal. A signal
that comes while the outputs are moved into place waits until they all are,
and the line says so.
"""

from jaxadapt.cli._main import main, run

__all__ = ["main", "run"]
