"""The ``fgins`` console command's entry point: Ctrl-C while the CLI's modules are still
being imported (numpy, GTSAM: the first ~0.5 s) ends like Ctrl-C anywhere else, with one
line and exit 130, not a KeyboardInterrupt traceback."""

from __future__ import annotations

import sys

EXIT_INTERRUPTED = 130


def interruption(
    exc: BaseException, kinds: tuple[type[BaseException], ...] = (KeyboardInterrupt,)
) -> BaseException | None:
    """The ``kinds`` exception (Ctrl-C, or the CLI's SIGTERM exception) that ``exc`` was
    raised from or while handling, if any. A signal that lands while an extension module
    initialises comes back wrapped: GTSAM's import turns a KeyboardInterrupt inside numpy
    into ``ImportError: initialization failed`` whose ``__cause__`` is the interrupt."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        if isinstance(current, kinds):
            return current
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return None


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
