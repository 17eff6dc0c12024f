"""The public surface as a new user touches it: the README's snippets, the ``jaxrt`` names."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def _python(code: str, cwd, timeout=600) -> subprocess.CompletedProcess:
    # HOME in the test's directory: the README's compile-cache lines write under ~/.cache
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env=dict(os.environ, HOME=str(cwd)))


def test_jaxrt_render_stays_the_function(tmp_path):
    """``jaxrt.render`` is the function however often it is called and whatever was imported
    before: the driver module is ``jaxrt.rendering.driver``, so no submodule of the package
    shares the function's name."""
    code = textwrap.dedent("""
        import types
        import jaxrt
        a = jaxrt.render
        import jaxrt.rendering.driver
        from jaxrt.rendering.driver import RenderResult, render
        b = jaxrt.render
        assert all(isinstance(f, types.FunctionType) for f in (a, b, jaxrt.render)), (
            a, b, jaxrt.render)
        assert a is b is jaxrt.render is render
        assert issubclass(jaxrt.RenderInterrupted, KeyboardInterrupt)
        assert jaxrt.RenderResult is RenderResult
        print("OK")
    """)
    out = _python(code, tmp_path)
    assert out.returncode == 0 and "OK" in out.stdout, out.stderr[-2000:]


def readme_python_snippets() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)


# The README's sizes, shrunk so that its snippets run in seconds (the API calls are unchanged).
SHRINK = [(r"width=\d+", "width=16"), (r"height=\d+", "height=12"), (r"spp=\d+", "spp=4"),
          (r"time_budget=[\d.]+", "time_budget=0.5"), (r"10\*\*6|num_samples=\d+", "10**4")]


@pytest.mark.slow  # ~60 s: every README snippet, twice, in a fresh interpreter
def test_readme_python_snippets_run_twice(tmp_path):
    snippets = readme_python_snippets()
    assert len(snippets) >= 3
    code = "\n".join(snippets)
    for pattern, repl in SHRINK:
        code = re.sub(pattern, repl, code)
    # each snippet as written, then all of them again in the same interpreter
    script = code + "\n" + code + "\nprint('README OK')\n"
    out = _python(script, tmp_path)
    assert out.returncode == 0 and "README OK" in out.stdout, out.stderr[-3000:]
