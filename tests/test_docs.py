"""The documentation in ``docs/``: it builds with warnings as errors, and its code runs.

Every ```` ```python ```` block of every ``docs/*.md`` page is executed, each page's blocks in
order in one namespace, in a fresh interpreter whose working directory and ``HOME`` are the
test's temporary directory (files the examples write, and the compile caches some of them
switch on, land there). A block that is deliberately not runnable is fenced as
```` ```python no-run ````; that is for rare cases (a snippet that needs a cluster, say).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = sorted(DOCS.glob("*.md"))

#: a fenced block: its info string after ``python`` (e.g. " no-run") and its body
FENCE = re.compile(r"^```python([^\n]*)\n(.*?)^```[ \t]*$", re.M | re.S)
NO_RUN = "no-run"


def python_blocks(page: Path) -> list[tuple[int, str, bool]]:
    """(line, code, runnable) of every ```python block of ``page``, in order."""
    text = page.read_text(encoding="utf-8")
    blocks = []
    for m in FENCE.finditer(text):
        line = text.count("\n", 0, m.start()) + 1
        blocks.append((line, m.group(2), NO_RUN not in m.group(1).split()))
    return blocks


def _env(home: Path) -> dict:
    env = dict(os.environ, HOME=str(home), TMPDIR=str(home), MPLBACKEND="Agg",
               PYTHONPATH=str(ROOT))
    env.pop("JAXRT_NO_COMPILE_CACHE", None)
    return env


def _script(page: Path) -> str:
    """A script that runs the page's blocks in one namespace and names the block that fails."""
    parts = ["import sys, traceback", "namespace = {'__name__': '__main__'}"]
    for line, code, runnable in python_blocks(page):
        if not runnable:
            continue
        label = f"{page.name}:{line}"
        parts.append(
            f"try:\n"
            f"    exec(compile({code!r}, {label!r}, 'exec'), namespace)\n"
            f"except BaseException:\n"
            f"    traceback.print_exc()\n"
            f"    sys.exit('docs block failed: {label}')")
    parts.append(f"print('DOCS OK {page.name}')")
    return "\n".join(parts) + "\n"


def test_every_page_is_in_the_toctree():
    index = (DOCS / "index.md").read_text(encoding="utf-8")
    toctree = re.search(r"```\{toctree\}(.*?)```", index, re.S).group(1)
    listed = {line.strip() for line in toctree.splitlines()
              if line.strip() and not line.strip().startswith(":")}
    assert listed == {p.stem for p in PAGES if p.stem != "index"}


def test_the_fence_parser():
    """The extraction this file relies on: info strings, order, the no-run marker."""
    assert FENCE.findall("```python\na = 1\n```\ntext\n```python no-run\nb\n```\n"
                         "```bash\nc\n```\n") == [("", "a = 1\n"), (" no-run", "b\n")]
    blocks = [b for page in PAGES for b in python_blocks(page)]
    assert sum(runnable for *_, runnable in blocks) >= 20  # the pages show working code
    assert sum(not runnable for *_, runnable in blocks) <= 3  # and rarely code that is not


#: a path into the repository, as README.md and the pages cite one in backticks
REPO_PATH = re.compile(r"`((?:docs|benchmarks|examples|tests|jaxrt|\.ci)/[\w./-]*\w)`")


@pytest.mark.parametrize("page", [ROOT / "README.md", *PAGES], ids=lambda p: p.name)
def test_cited_files_exist(page):
    """Every relative link and every repository path in backticks names a file or folder
    of this repository (README links are relative to the root, the pages' to docs/)."""
    text = page.read_text(encoding="utf-8")
    missing = []
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        target = target.split("#")[0]
        if target and not re.match(r"[a-z]+:", target) \
                and not (page.parent / target).exists():
            missing.append(target)
    missing += [p for p in REPO_PATH.findall(text) if not (ROOT / p).exists()]
    assert missing == []


@pytest.mark.slow  # every page's code: a few compiles of tiny renders each (~10-60 s a page)
@pytest.mark.parametrize("page", [p for p in PAGES if any(r for *_, r in python_blocks(p))],
                         ids=lambda p: p.name)
def test_page_code_runs(page, tmp_path):
    out = subprocess.run([sys.executable, "-c", _script(page)], cwd=tmp_path,
                         capture_output=True, text=True, timeout=900, env=_env(tmp_path))
    assert out.returncode == 0 and f"DOCS OK {page.name}" in out.stdout, \
        (out.stdout[-2000:] + "\n" + out.stderr[-4000:])


def test_docs_build_without_warnings(tmp_path):
    """``sphinx-build -W --keep-going -b html docs <tmp>``: MyST pages and the autodoc API
    reference, every warning an error."""
    out = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b",
                          "html", str(DOCS), str(tmp_path / "html")], cwd=ROOT,
                         capture_output=True, text=True, timeout=900,
                         env=_env(tmp_path))
    assert out.returncode == 0, out.stderr[-6000:]
    assert (tmp_path / "html" / "index.html").exists()
    assert (tmp_path / "html" / "api.html").exists()
