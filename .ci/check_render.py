"""Check what the README's first command wrote into ``out/``: frames, a
video, a contact sheet and the adaptation plot, none of them blank. Exits
with 1 and says what is missing or blank."""

import sys
from pathlib import Path

import numpy as np
from PIL import Image

out = Path(sys.argv[1] if len(sys.argv) > 1 else "out")
problems = []
frames = sorted(out.glob("frame_*.png"))
if not frames:
    problems.append("no frame_*.png")
for name in (
    "contact_sheet.png",
    "adaptation.png",
    *(f.name for f in frames[:: max(1, len(frames) // 4)]),
):
    path = out / name
    if not path.is_file():
        problems.append(f"no {name}")
        continue
    pixels = np.asarray(Image.open(path).convert("L"), float)
    if pixels.std() < 1.0:  # one flat colour: nothing drawn
        problems.append(f"{name} is blank (every pixel about {pixels.mean():.0f})")
video = out / "video.mp4"
if not video.is_file() or video.stat().st_size < 10_000:
    problems.append("no video.mp4 of at least 10 kB")
if problems:
    sys.exit(f"{out}: " + "; ".join(problems))
print(f"{out}: {len(frames)} frames, video.mp4, contact_sheet.png, adaptation.png, none blank")
