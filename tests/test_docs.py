"""The documentation's relative links point at files that exist (README, docs/, the shipped
results' own notes), so a reader who follows one from a fresh clone lands somewhere."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _markdown_files() -> list[Path]:
    files = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "docs").glob("*.md"))]
    files += sorted((ROOT / "results").rglob("*.md"))
    return [f for f in files if f.is_file()]


def _broken_links(md: Path) -> list[str]:
    broken = []
    for target in LINK.findall(md.read_text(encoding="utf-8")):
        if target.startswith(("http://", "https://", "mailto:", "#")):
            continue
        if not (md.parent / target.split("#")[0]).exists():
            broken.append(target)
    return broken


@pytest.mark.parametrize("md", _markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(md: Path) -> None:
    assert _broken_links(md) == []


def test_the_link_check_sees_a_broken_link(tmp_path: Path) -> None:
    (tmp_path / "there.md").write_text("x")
    md = tmp_path / "page.md"
    md.write_text("[ok](there.md#part) [web](https://example.org) [gone](missing/file.png) [anchor](#a)")
    assert _broken_links(md) == ["missing/file.png"]


def test_the_citation_file_names_the_paper_and_this_version():
    import tomllib

    import yaml

    root = Path(__file__).resolve().parents[1]
    cff = yaml.safe_load((root / "CITATION.cff").read_text())
    version = tomllib.loads((root / "pyproject.toml").read_text())["project"]["version"]
    assert cff["cff-version"] == "1.2.0" and cff["version"] == version
    paper = cff["preferred-citation"]
    assert paper["title"].startswith("Arbitrarily Scalable Environment Generators")
    assert [a["family-names"] for a in paper["authors"]] == ["Zhang", "Fontaine", "Bhatt", "Nikolaidis", "Li"]


def _map_misses(text: str, packages: list[str]) -> list[str]:
    """The packages the architecture map (the first fenced block, before any section or
    table) does not name."""
    head = re.split(r"\n\| where \| what \||\n## ", text, maxsplit=1)[0]
    blocks = re.findall(r"```\n(.*?)```", head, flags=re.S)
    if not blocks:
        return packages
    return [p for p in packages if f"{p}/" not in blocks[0]]


def test_the_architecture_doc_opens_with_a_map_of_every_package():
    packages = sorted(d.name for d in (ROOT / "nca_qd").iterdir() if (d / "__init__.py").is_file())
    assert len(packages) >= 8
    assert _map_misses((ROOT / "docs/architecture.md").read_text(encoding="utf-8"), packages) == []


def test_the_map_check_sees_a_missing_package():
    text = "# A\n\n```\nqd/ -> sim/\n```\n\n| where | what |\n```\nrepair/\n```\n"
    assert _map_misses(text, ["qd", "sim", "repair"]) == ["repair"]
    assert _map_misses("# A\n\n| where | what |\n", ["qd"]) == ["qd"]
