"""The README's "Python API" example runs as written (a doctest), on the quick start's session."""

from __future__ import annotations

import doctest
import re
import shutil
from pathlib import Path

README = Path(__file__).resolve().parents[2] / "README.md"


def _python_api_block() -> str:
    text = README.read_text(encoding="utf-8")
    section = text.split("## Python API", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert blocks, "the README's Python API section has no python block"
    return blocks[0]


def test_readme_python_api_example_runs(default_session_measured, tmp_path, capsys):
    demo = shutil.copytree(default_session_measured, tmp_path / "gonio-demo")  # the quick start's session
    capsys.readouterr()
    source = _python_api_block().replace("/tmp/gonio-demo", str(demo))
    test = doctest.DocTestParser().get_doctest(source, {}, "README Python API", str(README), 0)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.attempted >= 8 and result.failed == 0, capsys.readouterr().out
