"""Numerical checks run in float64; the float32 paths are tested explicitly."""

import jax

jax.config.update("jax_enable_x64", True)

from hypothesis import settings  # noqa: E402

# JAX dispatch makes the first example of each shape slow: no deadlines.
settings.register_profile("jaxadapt", deadline=None, max_examples=50)
settings.load_profile("jaxadapt")
