"""Whether an exception was raised from an interrupt that came back wrapped. No fgins
imports: the entry point and the CLI both use it, without an import cycle between them."""

from __future__ import annotations


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
