"""Regenerate the documentation's screenshots from the current layouts (``make screenshots``).

    .venv/bin/python docs/screenshots.py [--mrclam DIR] [--victoria DIR] [--out docs]

Each recording is made with ekfviz, then opened in the real viewer, off screen (``Xvfb``
when there is no display: ``apt-get install xvfb mesa-vulkan-drivers``), which writes a
PNG of its window. Rerun's config and data go to a throw-away directory, so no
notification or first-run banner is in the picture. The MRCLAM and Victoria Park
screenshots need the datasets (not in this repository): without ``--mrclam`` the
MRCLAM one shows a simulated dataset in the same layout, without ``--victoria`` none is made.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
DATA = ROOT / "data"
SIZE = "1600x1000"


def ekfviz(*args: str, env: dict[str, str], ok: tuple[int, ...] = (0,)) -> None:
    """Run an ekfviz command; stop on an exit status not in ``ok``."""
    done = subprocess.run([str(BIN / "ekfviz"), *args], env=env, capture_output=True, text=True)
    if done.returncode not in ok:
        sys.exit(f"ekfviz {' '.join(args)} failed:\n{done.stderr}")


def shoot(rrd: Path, png: Path, env: dict[str, str]) -> None:
    """Open ``rrd`` in the viewer off screen and save its window as ``png``."""
    subprocess.run(
        [str(BIN / "rerun"), "--screenshot-to", str(png), "--window-size", SIZE, str(rrd)],
        env=env,
        check=True,
        capture_output=True,
        timeout=300,
    )
    try:  # a display scaled 2x (HiDPI) writes twice the window's size: back to it
        from PIL import Image

        with Image.open(png) as image:
            width, height = (int(n) for n in SIZE.split("x"))
            if image.size != (width, height):
                image.resize((width, height), Image.Resampling.LANCZOS).save(png, optimize=True)
    except ImportError:  # Pillow is optional (matplotlib, a dependency of evo, brings it)
        pass
    print(f"wrote {png.relative_to(ROOT) if png.is_relative_to(ROOT) else png}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mrclam", type=Path, help="an MRCLAM dataset directory (robot 1)")
    parser.add_argument("--victoria", type=Path, help="the Victoria Park directory")
    parser.add_argument("--out", type=Path, default=ROOT / "docs")
    options = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="ekfviz-shots-") as temporary:
        work = Path(temporary)
        env = {
            **os.environ,
            "XDG_CONFIG_HOME": str(work / "config"),
            "XDG_DATA_HOME": str(work / "data"),
            "CI": "1",  # no analytics, no first-run banner
            "WINIT_X11_SCALE_FACTOR": "1",  # the PNG at the window's size
        }
        xvfb = None
        if not env.get("DISPLAY") and not env.get("WAYLAND_DISPLAY"):
            if shutil.which("Xvfb") is None:
                sys.exit("no display and no Xvfb: apt-get install xvfb mesa-vulkan-drivers")
            # a screen far larger than the window: the pointer starts at the screen's
            # centre, outside the window, so no hover tooltip is in the picture
            xvfb = subprocess.Popen(["Xvfb", ":97", "-screen", "0", "8000x5000x24"])
            env["DISPLAY"] = ":97"
            time.sleep(1.0)
        try:
            runs: list[tuple[str, list[str], tuple[int, ...]]] = [
                ("screenshot", ["replay", str(DATA / "classic.txt"), "--truth",
                                str(DATA / "classic_truth.json")], (0,)),
                ("compare", ["compare", str(DATA / "classic.txt"), "--truth",
                             str(DATA / "classic_truth.json"), "--filter", "ekf", "--filter",
                             "isam2", "--filter", "batch", "--workers", "1"], (0,)),
                ("sweep", ["sweep", str(DATA / "classic.txt"), "--truth",
                           str(DATA / "classic_truth.json"), "--preset", "tuning"], (0,)),
                ("check", ["check", str(DATA / "classic.txt"), "--filter",
                           f"{ROOT / 'tests' / 'plugins' / 'textbook.py'}:NoRInS"], (1,)),
            ]  # fmt: skip
            mrclam = options.mrclam
            if mrclam is None:
                mrclam = work / "MRCLAM_Sim"
                ekfviz("simulate", "--layout", "mrclam", "-o", str(mrclam), "--seed", "5",
                       "--duration", "300", env=env)  # fmt: skip
            runs.append(("mrclam", ["replay", str(mrclam), "--robot", "1"], (0,)))
            if options.victoria is not None:
                runs.append(("victoria", ["replay", str(options.victoria)], (0,)))
            options.out.mkdir(parents=True, exist_ok=True)
            for name, args, ok in runs:
                rrd = work / f"{name}.rrd"
                ekfviz(*args, "--save", str(rrd), env=env, ok=ok)
                shoot(rrd, options.out / f"{name}.png", env)
        finally:
            if xvfb is not None:
                xvfb.terminate()
                xvfb.wait()


if __name__ == "__main__":
    main()
