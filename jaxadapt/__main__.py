from jaxadapt._program import run

run()
