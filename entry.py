"""The ``fgins`` console command's entry point: Ctrl-C while the CLI's modules are still
being imported (numpy, GTSAM: the first ~0.5 s) ends like Ctrl-C anywhere else, with one
line and exit 130, not a KeyboardInterrupt traceback."""

from __future__ import annotations

import sys

from fgins.interrupts import interruption

EXIT_INTERRUPTED = 130


def main() -> int:
    try:
        from fgins.cli import main as cli_main

        return cli_main()
    except KeyboardInterrupt:
        print("fgins: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:
        if interruption(exc) is None:
            raise
        print("fgins: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
