"""The README's API example runs as written (on smaller frames)."""

import re
from pathlib import Path

import pytest

#: End-to-end or long: left out of the quick run (pytest -m "not slow").
pytestmark = pytest.mark.slow

README = Path(__file__).resolve().parent.parent / "README.md"


def test_the_api_example_runs_and_its_gradient_is_informative():
    code = re.search(r"```python\n(.*?)```", README.read_text(), re.S).group(1)
    assert "tunnel_drive(480, 270, duration=4.0)" in code
    namespace = {}
    exec(
        code.replace("tunnel_drive(480, 270, duration=4.0)", "tunnel_drive(48, 27, duration=2.0)"),
        namespace,
    )
    assert namespace["out"].shape == (60, 27, 48, 3)
    assert namespace["batch"].shape == (2, 60, 27, 48, 3)
    assert abs(float(namespace["grad"])) > 1e-3
