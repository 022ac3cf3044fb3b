"""The documentation (kind: property): the README's contract, the API
reference that is built from the docstrings, and the rule that docs,
docstrings and comments say what is true now rather than when or in which
work step it became so.

History belongs to git and ``CHANGELOG.md`` (which is not searched). What
:func:`test_no_history` flags, in ``README.md``, every page of ``docs/``
(results templates included), the Markdown files and configuration comments
shipped beside the code, and every docstring and ``#`` comment of the five
packages, ``tests/`` and ``benchmarks/``:

* an ISO date (a year, month and day joined by hyphens);
* a month's name with a year, the day between them or not;
* a numbered work step or issue: "stop", "issue", "deliverable" or "work
  step" followed by its number, and "stop-" joined to a number before
  "package", "model", "network" and the like;
* "until" followed by a year, "stop", "issue", "now", "then", "today" or
  "recently"; and "packaged" followed by "before", "until" or "since";
* ``(new)``, ``(new;``, ``(new,``: new is relative to a moment.

Allowed, because they are facts that do not age:

* editions of standards and specifications, ``ISO 12233:2023``,
  ``IEC 61966-2-1:1999``, ``DNG 1.7.1.0``;
* citations with their year, ``Malvar 2004``, ``(Burns, 2020)`` (a bare year
  is never flagged), and dated editions of a cited source: an ISO date right
  after "catalogue", "catalog", "data sheet(s)", "edition", "release" or
  "version" (a catalogue's edition date);
* data values in code, which are not docstrings or comments (an EXIF
  ``DateTime`` of ``"2026:11:21 12:00:00"`` in a test);
* algorithm and training steps, ``step 2`` of ISO 12233's procedure or
  ``step 0`` of a training run (only *work* steps are history), and index
  ranges such as ``start .. stop-1``.
"""

from __future__ import annotations

import ast
import importlib.util
import io
import re
import subprocess
import sys
import tokenize
from pathlib import Path

import pytest

pytestmark = pytest.mark.property

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("isp", "modules", "calibration", "restoration", "export")
CODE_TREES = (*PACKAGES, "tests", "benchmarks")

_MONTH = (r"(?:Jan(?:uary)?|Feb(?:ruary)?|Mar(?:ch)?|Apr(?:il)?|May|June?|July?|Aug(?:ust)?"
          r"|Sep(?:t(?:ember)?)?|Oct(?:ober)?|Nov(?:ember)?|Dec(?:ember)?)")
#: what reads as history, by name (the module docstring lists the forms)
HISTORY = {
    "date": re.compile(r"\b20\d\d-[01]\d-[0-3]\d\b"),
    "month and year": re.compile(rf"\b{_MONTH}\.?\s+(?:\d{{1,2}},?\s+)?(?:19|20)\d\d\b"),
    "work step": re.compile(r"\bstops?\s+\d+\b|\bstop-\d+(?=[\s-]+(?:package|model|network|column|figure|"
                            r"retrain|default|design))|\bwork[\s-]steps?\s+\d+\b|\bdeliverables?\s+\d+\b",
                            re.IGNORECASE),
    "issue number": re.compile(r"\bissues?\s+#?\d+\b", re.IGNORECASE),
    "until": re.compile(r"\buntil\s+(?:(?:19|20)\d\d\b|stop\b|issue\b|now\b|then\b|today\b|recently\b)",
                        re.IGNORECASE),
    "packaged before": re.compile(r"\bpackaged\s+(?:before|until|since)\b", re.IGNORECASE),
    "(new)": re.compile(r"\(new[);,]", re.IGNORECASE),
}
#: a dated edition of a cited source (see the module docstring)
EDITION = re.compile(r"\b(?:catalogue|catalog|data\s+sheets?|edition|release|version)\s+20\d\d-\d\d-\d\d\b",
                     re.IGNORECASE)


def history_in(text: str) -> list[str]:
    """The history forms found in one line of text, by name.

    >>> day, step = "-".join(["2026", "11", "25"]), " ".join(["stop", "12"])   # not written whole here
    >>> history_in(f"the window was 16 µm until {day} ({step})")
    ['date', 'work step', 'until']
    >>> history_in(f"ISO 12233:2023, IEC 61966-2-1:1999, Malvar 2004, Zemax catalogue {day}")
    []
    >>> history_in("indices start .. stop-1; step 2 of the e-SFR; at step 0 of training")
    []
    """
    text = EDITION.sub("", text)
    return [name for name, pattern in HISTORY.items() if pattern.search(text)]


def python_prose(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every docstring line and ``#`` comment of a Python file."""
    source = path.read_text(encoding="utf-8")
    out = []
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            out.append((tok.start[0], tok.string))
    for node in ast.walk(ast.parse(source, str(path))):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                    and isinstance(body[0].value.value, str):
                out += [(body[0].lineno + i, line) for i, line in enumerate(body[0].value.value.splitlines())]
    return out


def config_comments(path: Path) -> list[tuple[int, str]]:
    """(line, comment) of a TOML file: the text from each ``#`` outside a string."""
    out = []
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        quoted, cut = None, None
        for i, ch in enumerate(line):
            if quoted:
                quoted = None if ch == quoted else quoted
            elif ch in "\"'":
                quoted = ch
            elif ch == "#":
                cut = i
                break
        if cut is not None:
            out.append((n, line[cut:]))
    return out


def prose_files() -> list[tuple[Path, list[tuple[int, str]]]]:
    """Every text :func:`test_no_history` reads, with its lines."""
    md = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    md += [p for tree in PACKAGES for p in sorted((ROOT / tree).rglob("*.md"))]
    out = [(p, list(enumerate(p.read_text(encoding="utf-8").splitlines(), 1))) for p in md]
    out += [(p, config_comments(p)) for p in sorted((ROOT / "configs").glob("*.toml"))]
    for tree in CODE_TREES:
        out += [(p, python_prose(p)) for p in sorted((ROOT / tree).rglob("*.py"))
                if "__pycache__" not in p.parts and p != Path(__file__).resolve()]   # this file names the forms
    return out


def test_no_history():
    found = []
    for path, lines in prose_files():
        for n, text in lines:
            names = history_in(text)
            if names:
                found.append(f"{path.relative_to(ROOT)}:{n}: {', '.join(names)}: {text.strip()[:120]}")
    assert not found, ("history in docs, docstrings or comments (say what is true now; history goes to "
                       "CHANGELOG.md):\n" + "\n".join(found))


# -- the README ---------------------------------------------------------------------------------------

README = ROOT / "README.md"
#: the two set-up commands on a fresh machine: the main job, and the tests
SETUP = ('pip install -e . && isp demo',
         'pip install torch==2.13.0 && pip install -e ".[train,test,cluster]" && python -m pytest')


def test_readme_is_a_users_guide():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 300, f"README.md has {len(lines)} lines; results go to docs/results/, history to CHANGELOG.md"


def test_readme_setup_commands_and_ci():
    text = README.read_text(encoding="utf-8")
    for command in SETUP:
        assert f"\n{command}\n" in text, f"README.md lacks the set-up command {command!r}"
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert SETUP[1] in ci, ".ci/run must run the README's test command"


def test_readme_links_exist():
    text = README.read_text(encoding="utf-8")
    missing = [target for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
               if "://" not in target and not (ROOT / target).exists()]
    assert not missing, f"README.md links to files that do not exist: {missing}"


# -- the API reference ----------------------------------------------------------------------------------

def _api_pages_module():
    spec = importlib.util.spec_from_file_location("docs_api_pages", ROOT / "docs" / "api" / "_pages.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.skipif(importlib.util.find_spec("mkdocs") is None, reason="mkdocs is not installed (pip install -e .[docs])")
def test_api_pages_list_every_public_module():
    pages = _api_pages_module()
    for package in PACKAGES:
        page = (ROOT / "docs" / "api" / f"{package}.md").read_text(encoding="utf-8")
        assert f"<!-- modules: {package} -->" in page, f"docs/api/{package}.md does not list {package}'s modules"
        names = pages.public_modules(package)
        assert names[0] == package
        expected = {".".join(p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
                    for p in (ROOT / package).rglob("*.py")
                    if not any(part.startswith("_") and part != "__init__.py"
                               for part in p.relative_to(ROOT).parts)}
        assert set(names) == expected


@pytest.mark.skipif(importlib.util.find_spec("mkdocs") is None
                    or importlib.util.find_spec("mkdocstrings_handlers") is None,
                    reason="mkdocs or mkdocstrings[python] is not installed (pip install -e .[docs])")
def test_api_reference_builds(tmp_path):
    """``mkdocs build --strict``: every page, link and ``::: module`` reference
    resolves, and every docstring parses (about 15 s on 2 cores)."""
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet",
                          "--config-file", str(ROOT / "mkdocs.yml"), "--site-dir", str(tmp_path / "site")],
                         cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, f"mkdocs build --strict failed:\n{run.stdout[-4000:]}\n{run.stderr[-8000:]}"
    for package in PACKAGES:
        assert (tmp_path / "site" / "api" / package / "index.html").is_file()
