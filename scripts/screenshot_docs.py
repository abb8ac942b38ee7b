"""Every page of the built documentation site opened in headless Chromium: a screenshot of
each, and the console's errors (a missing script, a broken image).

    apt-get install -y chromium          # Debian's Chromium (not needed by the tests)
    make docs
    .venv/bin/python scripts/screenshot_docs.py --out out/docs-shots

Serves ``build/site`` on 127.0.0.1 at a free port, loads each page, writes
``<out>/<page>.png`` and prints one line per page with the console errors Chromium logged;
exit status 1 when any page logged one.
"""

from __future__ import annotations

import argparse
import functools
import http.server
import re
import shutil
import subprocess
import sys
import threading
from pathlib import Path

SITE = Path(__file__).resolve().parent.parent / "build" / "site"
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--hide-scrollbars",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--enable-logging=stderr", "--v=0", "--virtual-time-budget=4000")
CONSOLE = re.compile(r"CONSOLE\(\d+\)\] \"(?P<message>.*)\", source: (?P<source>\S+)")
NETWORK = re.compile(r"(Failed to load resource|net::ERR_\w+)")


def serve(site: Path) -> tuple[http.server.ThreadingHTTPServer, int]:
    """The site on 127.0.0.1 at a free port, served from a thread."""
    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args: object) -> None:
            pass

    handler = functools.partial(Quiet, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, server.server_address[1]


def shoot(browser: str, url: str, png: Path, size: str) -> list[str]:
    """Screenshot ``url`` into ``png``; the console errors Chromium logged while loading it."""
    png.parent.mkdir(parents=True, exist_ok=True)
    done = subprocess.run([browser, *FLAGS, f"--window-size={size}", f"--screenshot={png}", url],
                          capture_output=True, text=True, timeout=120)
    errors = [m.group("message") for m in CONSOLE.finditer(done.stderr)]
    errors += [line.strip() for line in done.stderr.splitlines() if NETWORK.search(line)]
    return errors


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("out/docs-shots"))
    parser.add_argument("--site", type=Path, default=SITE)
    parser.add_argument("--size", default="1400,1000", help="window size WIDTH,HEIGHT (px)")
    parser.add_argument("pages", nargs="*", help="pages to shoot (default: every page)")
    args = parser.parse_args()
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        sys.exit("screenshot_docs.py: no chromium on PATH (apt-get install -y chromium)")
    pages = args.pages or sorted(str(p.relative_to(args.site)) for p in args.site.rglob("*.html")
                                 if p.name != "404.html")
    server, port = serve(args.site)
    failed = 0
    try:
        for page in pages:
            png = args.out / (page.removesuffix(".html").replace("/", "_") + ".png")
            errors = shoot(browser, f"http://127.0.0.1:{port}/{page}", png, args.size)
            failed += bool(errors)
            print(f"{'ok   ' if not errors else 'ERROR'} {page}" +
                  "".join(f"\n      {e}" for e in errors))
    finally:
        server.shutdown()
    print(f"{len(pages)} pages, {failed} with console errors; screenshots in {args.out}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
