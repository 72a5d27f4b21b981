"""Batches of fits sharded over devices give the single-device result.

XLA fixes the number of CPU devices when JAX starts, so the eight-device run
is a fresh Python process with ``XLA_FLAGS`` set before ``import jax``.
"""

import json
import os
import subprocess
import sys
import textwrap

import jax.numpy as jnp
import numpy as np
import pytest

from jaxadapt.psychophysics import fit as F  # noqa: N812

SCRIPT = textwrap.dedent(
    """
    import json
    import jax
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np
    from jaxadapt.psychophysics import fit as F

    x = jnp.log10(jnp.array([14.0, 19, 27, 35, 49]) / 27)
    mu = 0.1 * jax.random.normal(jax.random.key(0), (203, 1))  # not a multiple of 8
    k = F.sample_counts(jax.random.key(1), jnp.full((203, 5), 30), F.psychometric(x, mu, 0.15))
    k = k.at[0].set(0.0).at[1].set(jnp.array([0, 0, 30, 30, 30]))  # degenerate ones too
    single = F.fit(x, k, 30)
    sharded = F.fit_sharded(x, k, 30)
    print(json.dumps({
        "devices": jax.device_count(),
        "shape": list(sharded.pse.shape),
        "single": {name: np.asarray(v).tolist() for name, v in single._asdict().items()},
        "sharded": {name: np.asarray(v).tolist() for name, v in sharded._asdict().items()},
    }))
    """
)


def test_eight_cpu_devices_give_the_single_device_fits():
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=8"}
    env["JAX_PLATFORMS"] = "cpu"
    run = subprocess.run(
        [sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, run.stderr[-3000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out["devices"] == 8 and out["shape"] == [203]
    single, sharded = out["single"], out["sharded"]
    for name in ("flags", "converged"):
        assert sharded[name] == single[name], name
    # Each device runs the same operations on its datasets; XLA may vectorise
    # a 26-dataset slice differently from 203 datasets, so allow rounding.
    for name in ("b0", "b1", "pse", "sigma", "se_pse", "loglik", "deviance"):
        np.testing.assert_allclose(sharded[name], single[name], rtol=1e-10, atol=1e-12)
    assert single["flags"][0] & F.ALL_SAME and single["flags"][1] & F.SEPARATION


def test_map_sharded_pads_and_unpads_and_names_bad_batches():
    out = F.map_sharded(lambda a, b: a * 2 + b.sum(axis=-1), jnp.arange(3.0), jnp.ones((3, 5)))
    np.testing.assert_array_equal(out, [5.0, 7.0, 9.0])
    with pytest.raises(ValueError, match="args: expected a common leading batch axis"):
        F.map_sharded(lambda a, b: a, jnp.ones(3), jnp.ones((4, 5)))
