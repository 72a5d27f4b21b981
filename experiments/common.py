"""What every experiment script shares: its command line and its results folder."""

import argparse
from pathlib import Path

RESULTS = Path(__file__).resolve().parent.parent / "results"


def setup(name, description):
    """Parse ``--smoke`` and ``--out``; return ``(args, folder)``, the folder created.

    ``--smoke`` asks for a small, fast run (small frames, few samples) that
    exercises the same code, and says so first: its numbers are not the
    full run's that the script's docstring and the docs quote. Results
    go to ``results/<name>/`` unless ``--out`` says otherwise.
    """
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--smoke", action="store_true", help="a small, fast run")
    parser.add_argument("--out", type=Path, default=RESULTS / name, help="results folder")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.smoke:
        print(
            f"{name}: smoke run (small frames, few samples): its numbers are not the full "
            "run's quoted in the docstring and the docs"
        )
    return args, args.out
