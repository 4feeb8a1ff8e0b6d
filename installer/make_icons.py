"""Draw the Talus application icon and derive every platform's icon file from it.

    python installer/make_icons.py            # writes resources/icons/talus.png (1024 px master),
                                              # app/icons/talus.png (256 px, shipped in the package),
                                              # installer/windows/talus.ico, installer/macos/talus.icns

The master PNG is the one source: the Windows .ico (16-256 px) and the macOS .icns
(16-1024 px) are resampled from it with Pillow, so the three platforms show the same picture.
Every file is written atomically (a temporary file renamed over the target).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from PIL import Image, ImageDraw

ROOT = Path(__file__).resolve().parents[1]
MASTER = ROOT / "resources" / "icons" / "talus.png"
PACKAGE_ICON = ROOT / "app" / "icons" / "talus.png"
ICO = ROOT / "installer" / "windows" / "talus.ico"
ICNS = ROOT / "installer" / "macos" / "talus.icns"
ICO_SIZES = [(16, 16), (24, 24), (32, 32), (48, 48), (64, 64), (128, 128), (256, 256)]


def draw(size: int = 1024) -> Image.Image:
    """Two X-ray beams (one per camera) crossing on a bone, on a rounded dark-blue tile."""
    s = size / 1024
    img = Image.new("RGBA", (size, size), (0, 0, 0, 0))
    d = ImageDraw.Draw(img)
    d.rounded_rectangle([int(40 * s), int(40 * s), int(984 * s), int(984 * s)], radius=int(190 * s),
                        fill=(22, 44, 78, 255))
    beam = Image.new("RGBA", (size, size), (0, 0, 0, 0))
    b = ImageDraw.Draw(beam)
    centre = (512 * s, 560 * s)
    for src, fill in (((150 * s, 170 * s), (90, 180, 255, 110)), ((874 * s, 170 * s), (255, 190, 90, 110))):
        sx, sy = src
        cx, cy = centre
        dx, dy = cx - sx, cy - sy
        nx, ny = -dy, dx
        norm = (nx * nx + ny * ny) ** 0.5
        nx, ny = nx / norm * 210 * s, ny / norm * 210 * s
        far = (sx + 1.9 * dx, sy + 1.9 * dy)
        b.polygon([src, (far[0] + nx, far[1] + ny), (far[0] - nx, far[1] - ny)], fill=fill)
        b.ellipse([sx - 34 * s, sy - 34 * s, sx + 34 * s, sy + 34 * s], fill=(*fill[:3], 255))
    tile_alpha = img.getchannel("A")
    img = Image.alpha_composite(img, beam)
    img.putalpha(tile_alpha)  # the beams stay inside the tile
    d = ImageDraw.Draw(img)
    bone = (236, 230, 214, 255)
    # a talus-like bone: a dome with a neck and a head
    d.ellipse([int(300 * s), int(450 * s), int(640 * s), int(720 * s)], fill=bone)
    d.rounded_rectangle([int(560 * s), int(520 * s), int(700 * s), int(640 * s)], radius=int(40 * s),
                        fill=bone)
    d.ellipse([int(630 * s), int(480 * s), int(780 * s), int(660 * s)], fill=bone)
    d.arc([int(330 * s), int(470 * s), int(610 * s), int(690 * s)], 200, 320, fill=(180, 170, 150, 255),
          width=max(1, int(14 * s)))
    return img


def _save(img: Image.Image, path: Path, **kwargs) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        img.save(tmp, format=kwargs.pop("format"), **kwargs)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--from-master", action="store_true",
                    help="derive the other files from resources/icons/talus.png instead of drawing it")
    args = ap.parse_args(argv)
    if args.from_master:
        if not MASTER.is_file():
            print(f"make_icons: {MASTER} not found (run without --from-master to draw it)", file=sys.stderr)
            return 1
        master = Image.open(MASTER).convert("RGBA")
    else:
        master = draw(1024)
        _save(master, MASTER, format="PNG", optimize=True)
    _save(master.resize((256, 256), Image.Resampling.LANCZOS), PACKAGE_ICON, format="PNG", optimize=True)
    _save(master, ICO, format="ICO", sizes=ICO_SIZES)
    _save(master, ICNS, format="ICNS")
    for path in (MASTER, PACKAGE_ICON, ICO, ICNS):
        print(f"{path.relative_to(ROOT)}  {path.stat().st_size} bytes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
