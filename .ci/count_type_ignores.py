"""Count the ``# type: ignore`` comments in product and test code, and check each names its reason.

Usage (from the repository root): ``python .ci/count_type_ignores.py --max 57``

Prints the total and the count per top-level folder, then exits 1 when the total is above
``--max`` or when an ignore does not have the form ``# type: ignore[code]  # reason``
(an error code, then a comment saying why the checker is wrong or cannot know better);
each offending line is listed as ``path:line``. Comments are found with ``tokenize``, so
the words inside a string or a docstring do not count, and this script never counts itself
(its own docs and patterns name the comment it looks for).
"""

from __future__ import annotations

import argparse
import io
import re
import sys
import tokenize
from collections import Counter
from pathlib import Path

FOLDERS = ("sim", "tools", "agents", "orchestrator", "benchmark", "prompts", "tests")
SELF = Path(__file__).resolve()
IGNORE = re.compile(r"#\s*type:\s*ignore\b")
# the accepted form: error code(s) in brackets, then a second comment with some words
EXPLAINED = re.compile(r"#\s*type:\s*ignore\[[a-z0-9-]+(,\s*[a-z0-9-]+)*\]\s+#\s*\S.*")


def ignores(path: Path) -> list[tuple[int, str]]:
    """(line, comment text) of every ``type: ignore`` comment in a Python file."""
    found: list[tuple[int, str]] = []
    with path.open("rb") as f:
        source = f.read()
    for tok in tokenize.tokenize(io.BytesIO(source).readline):
        if tok.type == tokenize.COMMENT and IGNORE.search(tok.string):
            found.append((tok.start[0], tok.string))
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max", type=int, required=True, help="most ignores allowed in total")
    parser.add_argument("--root", type=Path, default=Path(), help="repository root (default: .)")
    args = parser.parse_args(argv)

    per_folder: Counter[str] = Counter()
    unexplained: list[str] = []
    for folder in FOLDERS:
        for path in sorted((args.root / folder).rglob("*.py")):
            if path.resolve() == SELF:
                continue
            for line, text in ignores(path):
                per_folder[folder] += 1
                if not EXPLAINED.search(text):
                    unexplained.append(f"{path.relative_to(args.root)}:{line}: {text.strip()}")
    total = sum(per_folder.values())
    print(f"type: ignore comments: {total} (limit {args.max})")
    for folder in FOLDERS:
        if per_folder[folder]:
            print(f"  {folder}/: {per_folder[folder]}")
    failed = False
    if total > args.max:
        print(f"FAIL: {total} type: ignore comments, at most {args.max} allowed")
        failed = True
    if unexplained:
        print(f"FAIL: {len(unexplained)} without the form '# type: ignore[code]  # reason':")
        for entry in unexplained:
            print(f"  {entry}")
        failed = True
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
