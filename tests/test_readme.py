"""The README's first lines give the two fresh-machine commands, and CI runs the second one verbatim; the README
and the docs/ pages link to files and headings that exist, and the pages that list the code's parts stay in step."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def readme_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    block = text.split("```bash\n", 1)[1].split("```", 1)[0]
    return [line for line in block.splitlines() if line.strip()]


def test_readme_starts_with_exactly_two_commands() -> None:
    lines = (ROOT / "README.md").read_text().splitlines()
    assert lines[0].startswith("# ")
    assert lines[2] == "```bash"  # the commands come first
    commands = readme_commands()
    assert len(commands) == 2
    assert commands[0].endswith("vslam run")
    assert "pytest" in commands[1]


def test_ci_runs_the_readme_test_command_verbatim() -> None:
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert readme_commands()[1] in ci


# --------------------------------------------------------------------------------------------------
# The README is a front door and the docs/ pages hold the rest: both stay short and linked, and the pages that
# list what the code has (config keys, modules) stay in step with it.

MARKDOWN_LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def markdown_files() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def heading_anchors(path: Path) -> set[str]:
    """GitHub's anchors of a Markdown file's headings: lower case, punctuation dropped, spaces to hyphens."""
    anchors: set[str] = set()
    in_code = False
    for line in path.read_text().splitlines():
        if line.startswith("```"):
            in_code = not in_code
        elif not in_code and line.startswith("#"):
            title = line.lstrip("#").strip().lower()
            anchors.add(re.sub(r"[^\w\- ]", "", title).replace(" ", "-"))
    return anchors


def relative_links(path: Path) -> list[str]:
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.DOTALL)  # no links inside code blocks
    return [target for target in MARKDOWN_LINK.findall(text) if not re.match(r"[a-z]+:", target)]


def test_readme_is_at_most_250_lines() -> None:
    assert len((ROOT / "README.md").read_text().splitlines()) <= 250


def test_every_relative_link_points_at_an_existing_file_and_heading() -> None:
    broken = []
    for page in markdown_files():
        links = relative_links(page)
        assert page.name != "README.md" or any(link.startswith("docs/") for link in links)
        for link in links:
            file_part, _, anchor = link.partition("#")
            target = (page.parent / file_part).resolve() if file_part else page
            if not target.is_file():
                broken.append(f"{page.name}: {link} (no such file)")
            elif anchor and target.suffix == ".md" and anchor not in heading_anchors(target):
                broken.append(f"{page.name}: {link} (no such heading)")
    assert not broken, broken


def test_readme_picture_is_a_small_png_in_docs() -> None:
    pictures = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", (ROOT / "README.md").read_text())
    assert pictures and all(p.startswith("docs/") and p.endswith(".png") for p in pictures)
    for picture in pictures:
        data = (ROOT / picture).read_bytes()
        assert data.startswith(b"\x89PNG") and len(data) <= 150_000


def test_config_page_lists_every_key_with_its_default() -> None:
    from vslam_core.config import EngineConfig
    from vslam_core.config_file import flat_values

    page = (ROOT / "docs" / "config.md").read_text()
    missing = []
    shipped = EngineConfig(threads=EngineConfig.threads)  # the class's default: conftest gives test runs one thread
    for key, value in flat_values(shipped).items():
        section, _, name = key.rpartition(".")
        default = f'"{value}"' if isinstance(value, str) else str(value).lower() if isinstance(value, bool) \
            else repr(value)
        table = page.split(f"### `[{section}]`", 1)[1] if section else page.split("### Top level", 1)[1]
        if f"| `{name}` | {default} |" not in table.split("\n### ", 1)[0]:
            missing.append(f"{key} = {default}")
    assert not missing, missing


def test_layout_page_names_every_module() -> None:
    page = (ROOT / "docs" / "layout.md").read_text()
    packages = [ROOT / "app" / "vslam", ROOT / "vslam_core"]
    unnamed = [str(path.relative_to(ROOT)) for package in packages for path in package.rglob("*.py")
               if path.name not in ("__init__.py", "__main__.py") and path.name not in page]
    folders = [str(path.relative_to(ROOT)) for package in packages for path in package.rglob("*/")
               if path.is_dir() and path.name != "__pycache__" and f"{path.name}/" not in page]
    assert not unnamed and not folders, unnamed + folders
