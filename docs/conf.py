"""Sphinx configuration of jaxrt's documentation: Markdown pages (myst-parser) and the API
reference from the docstrings (autodoc + napoleon). Build with

    sphinx-build -W --keep-going -b html docs /tmp/docs_html

(``tests/test_docs.py`` runs exactly that, and every ```python block of the pages).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the package from this checkout, installed or not

# importing jaxrt's modules must not compile or allocate much: autodoc only reads them
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jaxrt  # noqa: E402

project = "jaxrt"
author = "the jaxrt authors"
copyright = "the jaxrt authors, MIT licence"
release = version = jaxrt.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
]

source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]

# Markdown: $...$ and $$...$$ maths, ::: fences, heading anchors for links between pages
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# The API reference: the docstrings as written (Google style for Args/Returns, RST roles for
# cross-references), members in source order, private names left out.
autodoc_default_options = {
    "members": True,
    "member-order": "bysource",
    "undoc-members": False,
    "show-inheritance": False,
}
autodoc_typehints = "signature"
autodoc_preserve_defaults = True
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False
napoleon_use_ivar = True  # "Attributes:" as fields, not a second description of each field
# A docstring's :func:`jaxrt.x.y` that names something the reference does not document (a
# private helper, a JAX or numpy object) stays plain text rather than failing the build.
nitpicky = False

html_theme = "alabaster"
html_title = f"jaxrt {release}"
html_static_path: list[str] = []
html_theme_options = {
    "description": "Batched Monte Carlo estimators for physically based rendering in JAX",
    "fixed_sidebar": True,
    "page_width": "1100px",
    "sidebar_width": "230px",
}


# --- docstrings whose markup docutils cannot read ----------------------------------------
#
# jaxrt's docstrings are written for readers of the source: |x| for an absolute value, tables
# and indented continuation lines. Two adjustments keep the reference readable and the build
# free of warnings without touching the source:
#
# 1. |...| outside inline literals is an absolute value, never an RST substitution (no
#    docstring defines one), so its bars are escaped;
# 2. a docstring that docutils still reports a problem in (an indented line where a
#    paragraph was expected, a simple table whose text crosses a column) is shown as
#    written, in a literal block, rather than half parsed. Such docstrings are listed by
#    ``sphinx-build -v`` ("shown verbatim"): fixing their markup in the source brings them
#    back as formatted text.

import inspect  # noqa: E402
import io  # noqa: E402
import re  # noqa: E402

import docutils.core  # noqa: E402
import docutils.nodes  # noqa: E402
import docutils.parsers.rst.directives  # noqa: E402
from sphinx.util import logging as sphinx_logging  # noqa: E402

_logger = sphinx_logging.getLogger("jaxrt.docs")
_LITERAL = re.compile(r"(``.+?``)")
_BARS = re.compile(r"(?<![\\|\w])\|(?=\S)([^|`\n]*?\S)\|(?![|\w])")
_ROLE = re.compile(r":[a-z:]+:`([^`]*)`")
_DIRECTIVE = re.compile(r"^(\s*\.\. )([\w:-]+)::", re.M)
_DOCUTILS = set(docutils.parsers.rst.directives._directive_registry)


def _escape_bars(line: str) -> str:
    parts = _LITERAL.split(line)
    return "".join(p if i % 2 else _BARS.sub(r"\\|\1\\|", p) for i, p in enumerate(parts))


def _problems(text: str) -> list[str]:
    """docutils' complaints about ``text``, parsed by plain docutils outside Sphinx: Sphinx's
    roles become docutils' own ``:literal:`` and Sphinx's directives (``.. attribute::``,
    ``.. seealso::``, ...) a ``.. note::``, which parse the same way. A parse that fails
    outright counts as a problem."""
    text = _ROLE.sub(lambda m: ":literal:`" + m.group(1) + "`", text)
    text = _DIRECTIVE.sub(lambda m: m.group(1) + (m.group(2) if m.group(2) in _DOCUTILS
                                                   else "note") + "::", text)
    stream = io.StringIO()
    try:
        doctree = docutils.core.publish_doctree(
            text, settings_overrides={"report_level": 2, "halt_level": 5,
                                      "warning_stream": stream,
                                      "file_insertion_enabled": False, "raw_enabled": False})
    except Exception as error:  # noqa: BLE001 - any failure means: show it as written
        return [f"{type(error).__name__}: {error}"]
    return [m.astext() for m in doctree.findall(docutils.nodes.system_message)
            if m["level"] >= 2]


def _docstring(app, what, name, obj, options, lines):
    module = getattr(obj, "__module__", None)
    if not lines or (what != "module" and module and not name.startswith(module + ".")):
        return  # empty, or an imported name autodoc looks at only to leave it out
    escaped = [_escape_bars(line) for line in lines]
    if not _problems("\n".join(escaped)):
        lines[:] = escaped
        return
    _logger.verbose("docstring of %s shown verbatim (docutils cannot parse it)", name)
    raw = inspect.getdoc(obj)  # as written, before napoleon turned Args: into fields
    original = raw.splitlines() if raw else list(lines)
    lines[:] = ["::", ""] + ["    " + line if line else "" for line in original] + [""]


# --- the public names ---------------------------------------------------------------------
#
# Docstrings cite the public names as :func:`jaxrt.render`; they are documented where they
# are defined (``jaxrt._LAZY`` says where), so a reference to one resolves to that.

def _public_name(app, env, node, contnode):
    target = node.get("reftarget", "")
    if node.get("refdomain") != "py" or not target.startswith("jaxrt."):
        return None
    where = jaxrt._LAZY.get(target[len("jaxrt."):])
    if where is None:
        return None
    return env.get_domain("py").resolve_xref(env, node["refdoc"], app.builder, node["reftype"],
                                             ".".join(where), node, contnode)


def setup(app):
    # after napoleon (priority 500), which turns Args:/Returns: into fields first
    app.connect("autodoc-process-docstring", _docstring, priority=900)
    app.connect("missing-reference", _public_name)
