import sys

from jaxadapt.cli import main

sys.exit(main())
