"""Regenerate the documentation's screenshots from the current default layouts
(``make screenshots``).

    .venv/bin/python docs/screenshots.py [--mrclam DIR] [--victoria DIR] [--out docs]
                                         [--only NAME ...]

Each recording is made with ekfviz from data this script generates (the bundled sample,
simulated logs, a simulated MRCLAM directory, a generated Victoria Park run, a ROS 2 bag
written from a simulated run), then opened in the real viewer, headless, which writes a
1600x1000 PNG of what a user sees once the whole file has loaded (``rerun
--screenshot-to`` took its picture while a large file was still loading: half a map).
The viewer needs a graphics stack, a GPU or Mesa's lavapipe (``apt-get install
mesa-vulkan-drivers``); its config and data go to a throw-away directory per picture, so
no layout of an earlier recording, notification or first-run banner is in it. With
``--mrclam`` and ``--victoria`` the real datasets are shown instead of generated ones.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
DATA = ROOT / "data"
PLUGINS = ROOT / "tests" / "plugins" / "textbook.py"
SIZE = "1600x1000"
LOAD_TIMEOUT_S = 120.0
SETTLE_S = 2.0  # after the load: the viewer lays out and draws a few frames


def ekfviz(*args: str, env: dict[str, str], ok: tuple[int, ...] = (0,)) -> None:
    """Run an ekfviz command; stop on an exit status not in ``ok``."""
    done = subprocess.run([str(BIN / "ekfviz"), *args], env=env, capture_output=True, text=True)
    if done.returncode not in ok:
        sys.exit(f"ekfviz {' '.join(args)} failed:\n{done.stderr}")


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


def shoot(rrd: Path | list[Path], png: Path, env: dict[str, str]) -> None:
    """Open ``rrd`` (or several, in turn: the last one is shown) in a headless viewer of
    its own, wait until it has loaded, and save its window as ``png``."""
    from rerun.experimental import ViewerClient

    port = free_port()
    viewer = subprocess.Popen(
        [str(BIN / "rerun"), "--headless", "--window-size", SIZE, "--port", str(port),
         "--hide-welcome-screen"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + LOAD_TIMEOUT_S
        while True:  # the viewer answers once its server is up
            try:
                client = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
                client.get_state()
                break
            except Exception:  # not up yet (the client raises its own kinds)
                if time.monotonic() > deadline or viewer.poll() is not None:
                    raise
                time.sleep(0.3)
        for one in rrd if isinstance(rrd, list) else [rrd]:
            client.open(str(one))
            while client.get_state().loading:
                if time.monotonic() > deadline:
                    sys.exit(f"the viewer did not finish loading {one} in {LOAD_TIMEOUT_S:.0f} s")
                time.sleep(0.3)
        time.sleep(SETTLE_S)
        client.save_screenshot(str(png))
    finally:
        # the rerun script starts the viewer binary: end the whole group it leads
        os.killpg(viewer.pid, signal.SIGTERM)
        viewer.wait()
    print(f"wrote {png.relative_to(ROOT) if png.is_relative_to(ROOT) else png}")


def generated_inputs(work: Path, env: dict[str, str], options: argparse.Namespace) -> None:
    """The simulated logs, MRCLAM directory, Victoria Park run and ROS 2 bag the
    screenshots replay (made in ``work``)."""
    sys.path.insert(0, str(ROOT / "tests"))
    if options.mrclam is None:
        options.mrclam = work / "MRCLAM_Sim"
        ekfviz("simulate", "--layout", "mrclam", "-o", str(options.mrclam), "--seed", "5",
               "--duration", "300", env=env)  # fmt: skip
    if options.victoria is None:
        from parks import make_park

        options.victoria = work / "VictoriaPark"
        options.victoria.mkdir()
        make_park(options.victoria, seed=1, seconds=120.0)
    ekfviz("simulate", "--scenario", "loop", "--steps", "300", "--landmarks", "60", "-o",
           str(work / "loop.txt"), "--truth-out", str(work / "loop.json"), env=env)  # fmt: skip
    from sources.test_rosbag import write_bag

    from ekfviz.sim.scenarios import classic

    write_bag(work / "run_bag", classic().run(seed=4))


def runs(work: Path, options: argparse.Namespace) -> list[tuple[str, list[str], tuple[int, ...]]]:
    """(picture name, ekfviz arguments, exit statuses that are fine) of every layout."""
    classic, truth = str(DATA / "classic.txt"), str(DATA / "classic_truth.json")
    scans_truth = str(DATA / "scans_truth.json")
    compared = [classic, "--truth", truth, "--workers", "1"]
    filters = ["--filter", "ekf", "--filter", f"{PLUGINS}:Textbook", "--filter", "isam2",
               "--filter", "batch"]  # fmt: skip
    return [
        ("screenshot", ["replay", classic, "--truth", truth], (0,)),
        ("loop", ["replay", str(work / "loop.txt"), "--truth", str(work / "loop.json")], (0,)),
        ("scans", ["replay", str(DATA / "scans.txt"), "--truth", scans_truth], (0,)),
        ("mrclam", ["replay", str(options.mrclam), "--robot", "1"], (0,)),
        ("victoria", ["replay", str(options.victoria)], (0,)),
        ("rosbag", ["replay", str(work / "run_bag")], (0,)),
        # the README's: the EKF, iSAM2 and the batch optimum
        ("compare", ["compare", *compared, *filters[:2], *filters[4:]], (0,)),
        ("compare-identical", ["compare", *compared, *filters[:4]], (0,)),
        ("compare4", ["compare", *compared, *filters], (0,)),
        ("sweep", ["sweep", classic, "--truth", truth, "--preset", "tuning"], (0,)),
        ("check", ["check", classic, "--filter", f"{PLUGINS}:NoRInS"], (1,)),
        ("consistency", ["consistency", "--runs", "5"], (0,)),
    ]


def watched_runs(work: Path, env: dict[str, str]) -> list[Path]:
    """Three runs of ``ekfviz watch`` on the bundled sample, the course skeleton edited
    between them (correct; R left out of S; R ten times too large), each run's recording
    kept: the second and third show the run before as a ghost."""
    folder = work / "watched"
    folder.mkdir()
    module = folder / "ekf_slam.py"
    original = (ROOT / "examples" / "course_skeleton" / "ekf_slam.py").read_text()
    module.write_text(original)
    report, latest = folder / "latest.json", folder / "latest.rrd"
    command = [str(BIN / "ekfviz"), "watch", str(module), str(DATA / "classic.txt"),
               "--save", str(latest), "--report", str(report)]  # fmt: skip
    watch = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, start_new_session=True)
    kept = []
    edits = ["S = H @ P @ H.T", "S = H @ P @ H.T + 10 * measure_cov"]
    try:
        for run in (1, 2, 3):
            deadline = time.monotonic() + LOAD_TIMEOUT_S
            while not report.exists() or json.loads(report.read_text()).get("run") != run:
                if time.monotonic() > deadline or watch.poll() is not None:
                    sys.exit(f"ekfviz watch did not report its run {run}")
                time.sleep(0.2)
            kept.append(folder / f"run{run}.rrd")
            kept[-1].write_bytes(latest.read_bytes())
            if run < 3:
                module.write_text(original.replace("S = H @ P @ H.T + measure_cov", edits[run - 1]))
    finally:
        os.killpg(watch.pid, signal.SIGINT)
        watch.wait()
    return kept


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mrclam", type=Path, help="an MRCLAM dataset directory (robot 1)")
    parser.add_argument("--victoria", type=Path, help="the Victoria Park directory")
    parser.add_argument("--out", type=Path, default=ROOT / "docs")
    parser.add_argument("--only", nargs="*", help="only these pictures (by name)")
    options = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="ekfviz-shots-") as temporary:
        work = Path(temporary)
        env = {**os.environ, "CI": "1"}  # no analytics
        generated_inputs(work, env, options)
        options.out.mkdir(parents=True, exist_ok=True)
        for name, args, ok in runs(work, options):
            if options.only and name not in options.only:
                continue
            rrd = work / f"{name}.rrd"
            ekfviz(*args, "--save", str(rrd), env=env, ok=ok)
            own = {"XDG_CONFIG_HOME": str(work / name / "config"),
                   "XDG_DATA_HOME": str(work / name / "data")}  # fmt: skip
            shoot(rrd, options.out / f"{name}.png", {**env, **own})
        if not options.only or "watch" in options.only:
            own = {"XDG_CONFIG_HOME": str(work / "watch" / "config"),
                   "XDG_DATA_HOME": str(work / "watch" / "data")}  # fmt: skip
            shoot(watched_runs(work, env), options.out / "watch.png", {**env, **own})


if __name__ == "__main__":
    main()
