"""The API reference's docstring conversion (docs/griffe_rest.py): reST simple tables become
Markdown tables (continuation lines joined, a new row wherever a column before the last has
text), Sphinx roles code spans, a closing ``::`` a colon."""


from .conftest import REPO, load_script


def _module():
    return load_script(REPO / "docs" / "griffe_rest.py", "griffe_rest")


TEXT = """Intro with :mod:`engine_model.runtime` and :func:`~a.b.c`.

=====  =====  ==========
table  key    meaning
=====  =====  ==========
``t``  ``a``  first line
              continued
       ``b``  second | row
=====  =====  ==========

Example::

    code
"""


def test_tables_roles_and_literal_markers_become_markdown():
    md = _module().to_markdown(TEXT).splitlines()
    assert md[0] == "Intro with `engine_model.runtime` and `c`."
    i = md.index("| table | key | meaning |")
    assert md[i + 1:i + 4] == ["|---|---|---|", "| ``t`` | ``a`` | first line continued |",
                               "|  | ``b`` | second \\| row |"]
    assert "Example:" in md and "    code" in md
