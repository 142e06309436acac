"""Links in README.md, docs/, bench/ and bench/history/ resolve (fast: no network).

Every relative link must name a file or folder of the repository, and every ``#anchor``
a heading of the page it points to, slugged as GitHub slugs headings. External links
are listed here and only allowed to a few hosts: the documentation must read the same
offline, and no page may pull from a CDN.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest
from markdown_it import MarkdownIt
from markdown_it.token import Token

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted(
    [
        ROOT / "README.md",
        *(ROOT / "docs").glob("*.md"),
        *(ROOT / "bench").glob("*.md"),
        *(ROOT / "bench" / "history").glob("*.md"),
    ]
)

# Hosts an external link may point to (none is a CDN), and every external link the
# pages hold: a new one must be added here on purpose.
ALLOWED_HOSTS = frozenset({"github.com", "docs.python.org", "peps.python.org"})
EXTERNAL_LINKS: frozenset[str] = frozenset()

_BARE_URL = re.compile(r"https?://[^\s<>()\[\]`]+")
_MARKDOWN = MarkdownIt("commonmark")


@dataclass(frozen=True)
class Link:
    page: Path
    line: int
    target: str

    def __str__(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}: {self.target}"


def github_slug(heading: str) -> str:
    """GitHub's anchor for a heading's text: lower case, punctuation dropped, spaces to -."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _inline_text(token: Token) -> str:
    """A heading's text as rendered: code spans keep their content, link syntax goes."""
    return "".join(
        child.content for child in token.children or [] if child.type in {"text", "code_inline"}
    )


def anchors(page: Path) -> set[str]:
    """The anchors of a page's headings; repeated headings get -1, -2, ... as on GitHub."""
    tokens = _MARKDOWN.parse(page.read_text())
    seen: dict[str, int] = {}
    found: set[str] = set()
    for opening, inline in zip(tokens, tokens[1:], strict=False):
        if opening.type != "heading_open":
            continue
        slug = github_slug(_inline_text(inline))
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        found.add(slug if count == 0 else f"{slug}-{count}")
    return found


def links(page: Path) -> Iterator[Link]:
    """Link and image targets, and bare URLs in prose (GitHub links those too)."""
    for token in _MARKDOWN.parse(page.read_text()):
        if token.type != "inline" or token.map is None:
            continue
        line = token.map[0] + 1
        in_link = False
        for child in token.children or []:
            if child.type in {"link_open", "image"}:
                attr = "href" if child.type == "link_open" else "src"
                yield Link(page, line, str(child.attrs[attr]))
            in_link = child.type == "link_open" or (in_link and child.type != "link_close")
            if child.type == "text" and not in_link:
                for url in _BARE_URL.findall(child.content):
                    yield Link(page, line, url)


def _all_links() -> list[Link]:
    return [link for page in PAGES for link in links(page)]


def _is_external(target: str) -> bool:
    return urlsplit(target).scheme != ""


def test_the_pages_exist_and_hold_links() -> None:
    names = {p.relative_to(ROOT).as_posix() for p in PAGES}
    assert {"README.md", "docs/README.md", "docs/api.md", "bench/RESULTS.md"} <= names
    assert any(name.startswith("bench/history/") for name in names)
    assert sum(1 for link in _all_links() if not _is_external(link.target)) > 20


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_resolve(page: Path) -> None:
    broken = []
    for link in links(page):
        if _is_external(link.target):
            continue
        parts = urlsplit(link.target)
        target = (page.parent / unquote(parts.path)).resolve() if parts.path else page
        if not target.exists() or ROOT not in (target, *target.parents):
            broken.append(f"{link} (no such file in the repository)")
        elif parts.fragment and (
            target.is_dir() or target.suffix != ".md" or parts.fragment not in anchors(target)
        ):
            broken.append(f"{link} (no heading with that anchor)")
    assert broken == []


def test_external_links_are_listed_and_allowed() -> None:
    external = {link.target for link in _all_links() if _is_external(link.target)}
    assert external == EXTERNAL_LINKS
    assert all(urlsplit(url).scheme == "https" for url in EXTERNAL_LINKS)
    assert all(urlsplit(url).hostname in ALLOWED_HOSTS for url in EXTERNAL_LINKS)


def test_python_m_commands_name_modules_of_the_repository() -> None:
    """A command moved or renamed in the code leaves no stale `python -m` in the pages."""
    outside = {"pip", "pytest"}  # the installer and the test runner, not ours
    named = {m for page in PAGES for m in re.findall(r"python -m ([\w.]+)", page.read_text())}
    ours = named - outside
    assert {"service", "bench.ik", "loadtest"} <= ours

    def runnable(module: str) -> bool:
        path = ROOT / module.replace(".", "/")
        return path.with_name(path.name + ".py").is_file() or (path / "__main__.py").is_file()

    assert [m for m in sorted(ours) if not runnable(m)] == []


def test_github_slugs() -> None:
    assert github_slug("HTTP API and errors") == "http-api-and-errors"
    assert (
        github_slug("Optimizer on the More-Garbow-Hillstrom set (bench/optimizer.py)")
        == "optimizer-on-the-more-garbow-hillstrom-set-benchoptimizerpy"
    )
    assert github_slug("Per problem: final f — analytic") == "per-problem-final-f--analytic"
