"""The studies in the guide: MkDocs (``mkdocs-gen-files``, ``mkdocs.yml``) runs this at build time.

Every study's Markdown and figures (``studies/<name>/``, not its run records) are added to the site at
``studies/<name>/``. Their links keep working in both places: a study links the guide as ``../../docs/<page>.md``
(right on GitHub), which the site reads as ``../../<page>.md``; the guide links a study as
``../studies/<name>/...``, which the site reads as ``studies/<name>/...``.
"""

from __future__ import annotations

import re
from pathlib import Path

import mkdocs_gen_files

ROOT = Path(__file__).resolve().parents[1]
KEPT = {".md", ".png"}
SKIPPED = {"runs", "superseded"}

for path in sorted((ROOT / "studies").rglob("*")):
    rel = path.relative_to(ROOT)
    if path.suffix not in KEPT or SKIPPED & set(rel.parts) or any(p.startswith("runs") for p in rel.parts):
        continue
    if path.suffix == ".md":
        with mkdocs_gen_files.open(rel.as_posix(), "w") as f:
            f.write(re.sub(r"\]\(((?:\.\./)+)docs/", r"](\1", path.read_text()))
    else:
        with mkdocs_gen_files.open(rel.as_posix(), "wb") as f:
            f.write(path.read_bytes())

for page in sorted((ROOT / "docs").glob("*.md")):
    text = page.read_text()
    if "](../studies/" in text:
        with mkdocs_gen_files.open(page.name, "w") as f:
            f.write(text.replace("](../studies/", "](studies/"))
