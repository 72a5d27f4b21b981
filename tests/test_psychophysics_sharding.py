"""Batches of fits sharded over devices give the single-device result.

XLA fixes the number of CPU devices when JAX starts, so the eight-device run
is a fresh Python process with ``XLA_FLAGS`` set before ``import jax``; it
gets the data from this process, which fits them on its single device in
the meantime.
"""

import json
import os
import subprocess
import sys
import textwrap

import jax.numpy as jnp
import numpy as np
import pytest

from jaxadapt.psychophysics import psychometric as F  # noqa: N812
from jaxadapt.psychophysics import sharding as S  # noqa: N812

#: End-to-end or long: left out of the quick run (pytest -m "not slow").
pytestmark = pytest.mark.slow

SCRIPT = textwrap.dedent(
    """
    import json
    import sys
    import jax
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np
    from jaxadapt.psychophysics import sharding as S

    with open(sys.argv[1]) as file:
        data = json.load(file)
    x, k = jnp.array(data["x"]), jnp.array(data["k"])
    sharded = S.fit_sharded(x, k, 30)
    print(json.dumps({
        "devices": jax.device_count(),
        "shape": list(sharded.pse.shape),
        "sharded": {name: np.asarray(v).tolist() for name, v in sharded._asdict().items()},
    }))
    """
)


def test_eight_cpu_devices_give_the_single_device_fits(tmp_path):
    # Drawn with NumPy (a jax.random.binomial would be compiled for this
    # shape alone before the eight-device process could start).
    rng = np.random.default_rng(0)
    x = np.log10(np.array([14.0, 19, 27, 35, 49]) / 27)
    mu = 0.1 * rng.normal(size=(203, 1))  # not a multiple of 8
    k = rng.binomial(30, np.asarray(F.psychometric(x, mu, 0.15))).astype(float)
    k[0], k[1] = 0.0, [0, 0, 30, 30, 30]  # degenerate ones too
    data = tmp_path / "data.json"
    data.write_text(json.dumps({"x": x.tolist(), "k": k.tolist()}))
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=8"}
    env["JAX_PLATFORMS"] = "cpu"
    run = subprocess.Popen(
        [sys.executable, "-c", SCRIPT, str(data)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    # The single-device fits, here on this process's one device, while the
    # eight-device process starts and compiles its sharded fit.
    single = {name: np.asarray(v).tolist() for name, v in F.fit(x, k, 30)._asdict().items()}
    try:
        stdout, stderr = run.communicate(timeout=300)
    finally:
        run.kill()  # nothing to do once it has exited
    assert run.returncode == 0, stderr[-3000:]
    out = json.loads(stdout.strip().splitlines()[-1])
    assert out["devices"] == 8 and out["shape"] == [203]
    sharded = out["sharded"]
    for name in ("flags", "converged"):
        assert sharded[name] == single[name], name
    # Each device runs the same operations on its datasets; XLA may vectorise
    # a 26-dataset slice differently from 203 datasets, so allow rounding.
    for name in ("b0", "b1", "pse", "sigma", "se_pse", "loglik", "deviance"):
        np.testing.assert_allclose(sharded[name], single[name], rtol=1e-10, atol=1e-12)
    assert single["flags"][0] & F.ALL_SAME and single["flags"][1] & F.SEPARATION


def test_map_sharded_pads_and_unpads_and_names_bad_batches():
    out = S.map_sharded(lambda a, b: a * 2 + b.sum(axis=-1), jnp.arange(3.0), jnp.ones((3, 5)))
    np.testing.assert_array_equal(out, [5.0, 7.0, 9.0])
    with pytest.raises(ValueError, match="args: expected a common leading batch axis"):
        S.map_sharded(lambda a, b: a, jnp.ones(3), jnp.ones((4, 5)))
