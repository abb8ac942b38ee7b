"""Screenshot of ``cellsight view`` replaying a run, with headless Chromium (the README's
picture, docs/view.png).

    apt-get install -y chromium          # Debian's Chromium (not needed by the tests)
    .venv/bin/cellsight run 3 --sensor ideal --out /tmp/e3i --overwrite
    .venv/bin/python scripts/screenshot_view.py /tmp/e3i --time 10 --seen-by cam2  # docs/view.png

Starts the view on 127.0.0.1 at a free port, waits until the camera images of the chosen frame
are drawn, and lets Chromium load the page and render the scene in software WebGL
(SwiftShader). Chromium's "software WebGL" notice is hidden for the picture.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from viser import _messages

from cellsight.view.app import ViewApp
from cellsight.view.replay import RunReplay

FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--enable-unsafe-swiftshader", "--use-gl=angle", "--use-angle=swiftshader",
         "--hide-scrollbars")
HIDE_NOTICES = ("const s = document.createElement('style');"
                "s.textContent = '.mantine-Notifications-root {display: none !important}';"
                "document.head.appendChild(s);")


def chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if path := shutil.which(name):
            return path
    sys.exit("screenshot_view: no chromium found (apt-get install -y chromium)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", help="output folder of 'cellsight run'")
    parser.add_argument("--time", type=float, default=10.0, help="frame time (s), default 10")
    parser.add_argument("--out", default="docs/view.png", help="PNG to write")
    parser.add_argument("--seen-by", metavar="CAMERA",
                        help="the camera whose view colours the features (default: the first)")
    parser.add_argument("--size", default="1400,900", help="window size W,H (px)")
    parser.add_argument("--budget-ms", type=int, default=40000,
                        help="Chromium's virtual time budget (ms) to load and render")
    args = parser.parse_args()
    replay = RunReplay(args.run_dir)
    app = ViewApp(replay.cell, replay=replay, start_time=args.time, port=0)
    try:
        if args.seen_by is not None:
            app.camera_choice.value = replay.cell.camera(args.seen_by).name
        if not app.worker.wait_idle(60.0) or app.worker.error is not None:
            sys.exit(f"screenshot_view: camera images failed: {app.worker.error}")
        # viser has no public call for it: run a snippet in each browser that connects
        app.server._websock_server.queue_message(
            _messages.RunJavascriptMessage(source=HIDE_NOTICES))
        out = Path(args.out).resolve()
        out.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory() as profile:
            command = [chromium(), *FLAGS, f"--user-data-dir={profile}",
                       f"--window-size={args.size}", f"--screenshot={out}",
                       f"--virtual-time-budget={args.budget_ms}", app.url]
            subprocess.run(command, check=True, timeout=180, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
        print(f"wrote {out} ({replay.caption(app.timeline.frame)})")
    finally:
        app.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
