"""Spawned worker processes and the script that starts them.

Collection workers (``collector.workers`` > 1, ``collector.sync=false``) and the validation env's worker are
spawned, never forked (libsumo runs one simulation per process, and a fork would copy the parent's). A spawned
process first imports the parent's ``__main__`` module again, under another name. A script that starts the
training in its module-level code, outside an ``if __name__ == "__main__":`` block, therefore starts it again in
every worker, and the worker dies before it answers. Whether the parent then learns of it depends on how the
worker's pipe reached it: TorchRL's multi-process collector waits on it forever. :func:`require_main_guard` says
so before any worker starts.
"""

from __future__ import annotations

import ast
import sys
from functools import lru_cache
from pathlib import Path


def _is_main_test(test: ast.expr) -> bool:
    """``__name__ == "__main__"`` (either side)."""
    if not (isinstance(test, ast.Compare) and len(test.ops) == 1 and isinstance(test.ops[0], ast.Eq)):
        return False
    sides = [test.left, test.comparators[0]]
    return any(isinstance(s, ast.Name) and s.id == "__name__" for s in sides) and any(
        isinstance(s, ast.Constant) and s.value == "__main__" for s in sides
    )


@lru_cache(maxsize=8)
def _guarded_lines(path: str) -> tuple[tuple[int, int], ...]:
    """The line ranges of ``path`` 's ``if __name__ == "__main__":`` bodies."""
    tree = ast.parse(Path(path).read_text(), filename=path)
    return tuple(
        (node.body[0].lineno, node.end_lineno)
        for node in ast.walk(tree)
        if isinstance(node, ast.If) and _is_main_test(node.test)
    )


def unguarded_main_call() -> tuple[str, int] | None:
    """(file, line) of the ``__main__`` script's module-level statement that is running this call, when that
    statement is outside every ``if __name__ == "__main__":`` block; None when it is inside one, when the call
    does not come from a script's module-level code (a function called later, an interactive session), or when
    ``__main__`` has no source file (``python -c``, a notebook: a spawned process then imports nothing again)."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if not path or not Path(path).is_file():
        return None
    script = Path(path).resolve()
    frame = sys._getframe(1)
    while frame is not None and not (
        frame.f_code.co_name == "<module>"
        and frame.f_globals is vars(main)
        and Path(frame.f_code.co_filename).resolve() == script  # the script's own code, not a shell's
    ):
        frame = frame.f_back
    if frame is None:
        return None
    line = frame.f_lineno
    try:
        guarded = _guarded_lines(str(path))
    except (OSError, SyntaxError, ValueError):  # source unreadable: nothing to say
        return None
    return None if any(lo <= line <= hi for lo, hi in guarded) else (str(path), line)


def require_main_guard(what: str) -> None:
    """Raises a ``RuntimeError`` naming the script and line when :func:`unguarded_main_call` finds one: ``what``
    (e.g. ``"collector.workers=2"``) is about to spawn worker processes, which would run that line again."""
    found = unguarded_main_call()
    if found is None:
        return
    path, line = found
    raise RuntimeError(
        f"{path}, line {line}: {what} spawns worker processes, and each one imports this script again; this line "
        'is outside an `if __name__ == "__main__":` block, so every worker would run it again and die. Put that '
        "code under the guard, or run `python -m kddrl_trl.train`"
    )
