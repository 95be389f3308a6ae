"""When to ``torch.compile``: one rule for the two compile sites (the fused transform stack and the learner).

The sites themselves are :func:`kddrl_trl.transforms.stack.compiled_frames` (the fused predictive-state stack)
and the learner's ``loss`` (:meth:`kddrl_trl.training.Learner._compile`, for every learner; its measured gain is
stated on :class:`kddrl_trl.training.HierarchicalLearner`).
"""
from __future__ import annotations

import logging
import shutil
from functools import lru_cache

log = logging.getLogger(__name__)


@lru_cache(maxsize=1)
def _compiler_found() -> bool:
    """Whether a C++ compiler is on the PATH (looked up, and logged, once per process)."""
    found = next((c for c in ("c++", "g++", "clang++") if shutil.which(c)), None)
    log.info("compile=auto: %s", f"{found} found, compiling" if found else "no C++ compiler on the PATH, eager")
    return found is not None


def resolve_compile(compile: bool | str) -> bool:
    """A ``compile`` option -> bool. ``"auto"`` compiles when a C++ compiler is on the PATH (the CPU backend of
    ``torch.compile`` needs one) and logs which way it went; anything else must be a bool."""
    if isinstance(compile, str):
        if compile.lower() in ("true", "false"):
            return compile.lower() == "true"
        if compile.lower() != "auto":
            raise ValueError(f"compile must be true, false or 'auto', got {compile!r}")
        return _compiler_found()
    if not isinstance(compile, bool):
        raise ValueError(f"compile must be true, false or 'auto', got {compile!r}")
    return compile
