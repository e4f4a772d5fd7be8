#!/usr/bin/env python3
"""Print the module map of the checkout as Markdown: one line per module, from its docstring.

  tools/module_map.py            # the map, grouped by layer and package
  tools/module_map.py --check docs/architecture.md   # exit 1 if the page's map is out of date

docs/architecture.md carries this output between the markers ``<!-- module-map -->`` and
``<!-- /module-map -->``; ``--write docs/architecture.md`` replaces that block.
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LAYERS = (
    ("Bottom layer: `scenenav/core/` (imports no other package of the project)", ("scenenav/core",)),
    ("Domain: `worlds/`", ("worlds",)),
    ("Domain: `sitl/`", ("sitl",)),
    ("Domain: `autopilot_bridge/`", ("autopilot_bridge",)),
    ("Domain: `perception/`", ("perception",)),
    ("Domain: `guidance/`", ("guidance",)),
    ("Top layer: `scenenav/app/` (may import everything)", ("scenenav/app",)),
)
BEGIN, END = "<!-- module-map -->", "<!-- /module-map -->"


def first_line(path: Path) -> str:
    doc = ast.get_docstring(ast.parse(path.read_text())) or ""
    line = " ".join(doc.strip().split("\n\n")[0].split())
    return line or "(no docstring)"


def module_map() -> str:
    out: list[str] = []
    for title, folders in LAYERS:
        out.append(f"**{title}**\n")
        out.append("| module | lines | what it is |")
        out.append("|---|---|---|")
        for folder in folders:
            for path in sorted((ROOT / folder).rglob("*.py")):
                rel = path.relative_to(ROOT)
                if folder == "scenenav" and rel.parts[1] in ("core", "app"):
                    continue
                n = len(path.read_text().splitlines())
                out.append(f"| `{rel.as_posix()}` | {n} | {first_line(path).replace('|', '/')} |")
        out.append("")
    return "\n".join(out).rstrip() + "\n"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    g = p.add_mutually_exclusive_group()
    g.add_argument("--check", type=Path, metavar="PAGE", help="exit 1 if PAGE's module map is stale")
    g.add_argument("--write", type=Path, metavar="PAGE", help="replace PAGE's module map block")
    args = p.parse_args()
    text = module_map()
    page = args.check or args.write
    if page is None:
        print(text, end="")
        return 0
    doc = page.read_text()
    if BEGIN not in doc or END not in doc:
        print(f"{page}: no {BEGIN} ... {END} block", file=sys.stderr)
        return 2
    head, rest = doc.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    new = f"{head}{BEGIN}\n{text}{END}{tail}"
    if args.check:
        if new != doc:
            print(f"{page}: module map is out of date; run tools/module_map.py --write {page}", file=sys.stderr)
            return 1
        return 0
    page.write_text(new)
    return 0


if __name__ == "__main__":
    sys.exit(main())
