"""The Python examples of the README and of docs/library.md run as written (issue 31): every
```python block of a page, in order, in one fresh interpreter (a later block may read what an
earlier one wrote), in an empty folder, with one torch thread."""

import os
import re
import subprocess
import sys

import pytest

from tests.conftest import REPO

PAGES = ("README.md", "docs/library.md")
BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)


def blocks(page: str) -> list[str]:
    return BLOCK.findall((REPO / page).read_text())


def test_the_library_page_has_an_example_for_every_stage():
    text = "\n".join(blocks("docs/library.md"))
    for call in ("load_sample()", "calibrate(", "discover(", "resolve_inputs(", ".fit(",
                 ".predict(", ".evaluate(", ".save(", "RulEstimator.load("):
        assert call in text, call


@pytest.mark.parametrize("page", [p for p in PAGES if blocks(p)])
def test_examples_run(page, tmp_path):
    script = "\n\n".join(blocks(page))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
           "PYTHONPATH": str(REPO)}
    r = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, f"{page}:\n{r.stdout}\n{r.stderr}"
