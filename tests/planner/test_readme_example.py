"""The README's planner example runs and prints what it says."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[2] / "README.md"


def test_readme_planner_example_runs(capsys):
    text = README.read_text(encoding="utf-8")
    section = text.split("## Planner", 1)[1].split("\n## ", 1)[0]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    exec(compile(code, "README.md", "exec"), {})
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "b 7.079"
    assert out[1].endswith("True")
