"""``python -m terrain_analysis.tools.sim2real_screenshot PAGE.html [-o PNG]``: the sim-to-real report as seen.

Renders the self-contained HTML page that ``terrain-sim2real -o DIR`` writes
(``DIR/diagnosis.html``) in Debian's chromium, headless, with every network
request refused (the page must need none), and saves a PNG screenshot of its
first screen (default 1280 × 900 CSS pixels: the verdict, where, the effect
table and one figure). ``make sim2real-screenshot`` diagnoses a shipped bag
and calls this.

Exit status: 0 the screenshot was written; 2 no chromium (``apt-get install
chromium``; or ``--browser PATH``), a missing page, or chromium wrote no image;
3 internal error.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

from terrain_estimation.cli import EXIT_OK, InputError, run_cli
from terrain_estimation.outputs import check_output_path

__all__ = ["BROWSERS", "find_browser", "main", "screenshot"]

PROG = "sim2real-screenshot"

#: Executable names of chromium, in order (Debian's package installs ``chromium``).
BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def find_browser(given: str | None = None) -> str:
    """The chromium executable: ``given`` (a path or a name on PATH), else the first of :data:`BROWSERS` on PATH.

    Raises:
        InputError: none found (the message says how to install it).
    """
    names = (given,) if given else BROWSERS
    for name in names:
        found = shutil.which(name)
        if found:
            return found
    if given:
        raise InputError(f"browser {given!r} not found or not executable")
    raise InputError(
        "chromium not found (looked for " + ", ".join(BROWSERS) + " on PATH); install Debian's chromium with "
        "`apt-get install chromium` (as root), or pass --browser PATH"
    )


def screenshot(
    page: str | Path,
    out: str | Path,
    *,
    browser: str | None = None,
    width: int = 1280,
    height: int = 900,
    timeout: float = 120.0,
    overwrite: bool = False,
) -> Path:
    """Render ``page`` headless in chromium and save a ``width`` × ``height`` PNG screenshot to ``out``.

    Network access is refused (every host name resolves to nothing), so a page
    that needed an external resource would show it missing. Raises
    :class:`InputError` when the page, the browser or the image is missing.
    """
    source = Path(page).resolve()
    if not source.is_file():
        raise InputError(f"{page}: no such HTML page (write it with terrain-sim2real BAG --vehicle V -o DIR)")
    # Before anything else: an existing file is replaced only with overwrite, and never the page itself.
    target = check_output_path(Path(out).resolve(), overwrite=overwrite, inputs=[source], kind="file")
    exe = find_browser(browser)
    target.parent.mkdir(parents=True, exist_ok=True)
    if target.exists():
        target.unlink()  # a previous screenshot (a regular file), allowed by overwrite
    with tempfile.TemporaryDirectory(prefix="sim2real-chromium-") as profile:
        command = [
            exe,
            "--headless",
            "--disable-gpu",
            "--hide-scrollbars",
            "--no-first-run",
            "--no-default-browser-check",
            "--disable-extensions",
            "--disable-background-networking",
            "--host-resolver-rules=MAP * ~NOTFOUND",
            f"--user-data-dir={profile}",
            f"--window-size={width},{height}",
            f"--screenshot={target}",
            source.as_uri(),
        ]
        if hasattr(os, "geteuid") and os.geteuid() == 0:
            command.insert(1, "--no-sandbox")  # chromium refuses to run as root with its sandbox
        try:
            done = subprocess.run(command, capture_output=True, text=True, timeout=timeout, check=False)
        except subprocess.TimeoutExpired as exc:
            raise InputError(f"{exe} did not finish within {timeout:g} s") from exc
    if not target.is_file() or not target.read_bytes().startswith(PNG_SIGNATURE):
        tail = "\n".join((done.stderr or "").strip().splitlines()[-5:])
        raise InputError(f"{exe} wrote no screenshot (exit status {done.returncode}){': ' + tail if tail else ''}")
    return target


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    parser.add_argument("page", nargs="?", help="the report's HTML page (DIR/diagnosis.html)")
    parser.add_argument("-o", "--output", help="PNG to write (default: screenshot.png beside the page)")
    parser.add_argument("--browser", help="chromium executable (default: chromium on PATH)")
    parser.add_argument("--width", type=int, default=1280, help="viewport width in CSS pixels (default 1280)")
    parser.add_argument("--height", type=int, default=900, help="viewport height in CSS pixels (default 900)")
    parser.add_argument("--overwrite", action="store_true", help="replace a previous screenshot at --output")
    parser.add_argument("--check", action="store_true", help="only check that chromium is there (exit 2 if not)")
    args = parser.parse_args(argv)

    def body() -> int:
        if args.check:
            print(f"{PROG}: using {find_browser(args.browser)}")
            return EXIT_OK
        if not args.page:
            raise InputError("give the report's HTML page (DIR/diagnosis.html)")
        out = Path(args.output) if args.output else Path(args.page).with_name("screenshot.png")
        path = screenshot(
            args.page, out, browser=args.browser, width=args.width, height=args.height, overwrite=args.overwrite
        )
        print(f"{PROG}: wrote {path} ({args.width} × {args.height})")
        return EXIT_OK

    return run_cli(PROG, body)


if __name__ == "__main__":
    sys.exit(main())
