"""The digest of rtsim's own source code, for what is kept on disk outside the checkout and made by that code
(generated kernel wrappers, the validation benchmark's generated runs and their truth). A cache keyed by its
inputs alone would hand back, after an edit of the code that made an entry, the old code's result: numba's
own cache has that flaw (it checks a kernel's own file only; tests/test_compile_resume.py shows it)."""
from __future__ import annotations

import functools
import hashlib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SOURCE_TREES = ("rtsim", "bridge", "drivers")


@functools.cache
def sources_digest(*trees: str) -> bytes:
    """SHA-256 over every .py file (its path relative to the repository and its bytes) under each of
    ``trees`` (folders relative to the repository root; none given: SOURCE_TREES), once per process."""
    h = hashlib.sha256()
    for tree in trees or SOURCE_TREES:
        for p in sorted((ROOT / tree).rglob("*.py")):
            h.update(str(p.relative_to(ROOT)).encode() + b"\0" + p.read_bytes() + b"\0")
    return h.digest()
