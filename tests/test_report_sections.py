"""Markdown section replacement used by benchmarks and examples."""
import pytest

from ocreach import ProblemError
from ocreach.fileio import replace_markdown_section


def test_replace_keeps_other_sections(tmp_path):
    p = tmp_path / "b.md"
    p.write_text("# Title\n\nintro\n\n## A\n\nold a\n\n## B\n\nold b\n")
    replace_markdown_section(p, "## A\n\nnew a")
    assert p.read_text() == "# Title\n\nintro\n\n## A\n\nnew a\n\n## B\n\nold b\n"
    replace_markdown_section(p, "## B\n\nnew b\n")
    assert p.read_text().endswith("## B\n\nnew b\n") and "new a" in p.read_text()
    replace_markdown_section(p, "## C\n\nc")
    assert p.read_text().endswith("old b\n".replace("old", "new") + "\n## C\n\nc\n")
    with pytest.raises(ProblemError, match="heading"):
        replace_markdown_section(p, "no heading")


def test_written_files_have_normal_permissions(tmp_path):
    import os

    p = replace_markdown_section(tmp_path / "c.md", "## A\n\nx")
    mask = os.umask(0)
    os.umask(mask)
    assert os.stat(p).st_mode & 0o777 == 0o666 & ~mask
