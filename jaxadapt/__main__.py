from jaxadapt.cli import run

run()
