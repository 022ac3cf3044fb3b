"""mkdocs hook: the API pages' module lists, read from the package tree.

A page of ``docs/api/`` holds a line ``<!-- modules: PACKAGE -->``; this hook
replaces it with one ``::: PACKAGE.MODULE`` directive (mkdocstrings) per public
module under ``PACKAGE/``, in path order, so a module that is added, moved or
split appears in the reference without an edit here. A module is public when no
part of its dotted name starts with an underscore (``__init__`` stands for its
package; ``__main__`` is left out). The hook also serves the repository's
``CHANGELOG.md`` as the site's ``changelog.md``, and renders doctests that a
docstring holds outside an ``Examples`` section (a module docstring's, or one
after ``Parameters``) as code rather than as Markdown text, in which an output
such as ``[[1, 2], [3, 4]]`` would read as a link; and shows the docstrings'
Sphinx cross-reference roles (``:func:`name```) as the code they name.
"""

from __future__ import annotations

import re
from pathlib import Path

from markdown import Extension
from markdown.preprocessors import Preprocessor
from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[2]
MARKER = re.compile(r"^<!-- modules: ([A-Za-z_][\w.]*) -->$", re.MULTILINE)


def public_modules(package: str, root: Path = ROOT) -> list[str]:
    """Dotted names of the public modules of ``package`` (a folder under ``root``),
    the package itself first, then its modules and subpackages in path order."""
    base = root.joinpath(*package.split("."))
    names = []
    for path in sorted(base.rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if any(p.startswith("_") for p in parts):
            continue
        names.append(".".join(parts))
    return sorted(names, key=lambda n: (n != package, n.split(".")))


FENCE = re.compile(r"^\s*(```|~~~)")
PROMPT = re.compile(r"^(\s*)>>> ")
ROLE = re.compile(r":(?:py:)?(?:func|class|meth|mod|data|attr|obj|exc|const):(`+)~?")


class _Doctests(Preprocessor):
    """Fence every doctest block (a ``>>>`` line and the lines after it up to a
    blank one) that is not already inside a fenced block, and drop the Sphinx
    roles in front of inline code outside fenced blocks."""

    def run(self, lines: list[str]) -> list[str]:
        out, fenced, i = [], False, 0
        while i < len(lines):
            line = lines[i]
            if FENCE.match(line):
                fenced = not fenced
            m = None if fenced else PROMPT.match(line)
            if m is None:
                out.append(line if fenced else ROLE.sub(r"\1", line))
                i += 1
                continue
            indent = m.group(1)
            out.append(f"{indent}```pycon")
            while i < len(lines) and lines[i].strip():
                out.append(lines[i])
                i += 1
            out.append(f"{indent}```")
        return out


class DoctestExtension(Extension):
    def extendMarkdown(self, md) -> None:   # noqa: N802 (Markdown's name)
        md.preprocessors.register(_Doctests(md), "doctest_fences", 27)


@event_priority(100)   # before mkdocstrings reads the Markdown extensions
def on_config(config):
    config.markdown_extensions.append(DoctestExtension())
    return config


def _directives(match: re.Match) -> str:
    return "\n\n".join(f"::: {name}" for name in public_modules(match.group(1)))


def on_page_markdown(markdown: str, page, config, files) -> str:
    return MARKER.sub(_directives, markdown)


def on_files(files, config):
    changelog = ROOT / "CHANGELOG.md"
    if changelog.is_file():
        files.append(File.generated(config, "changelog.md", content=changelog.read_text(encoding="utf-8")))
    return files
