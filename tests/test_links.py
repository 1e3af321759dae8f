"""Every relative link in every tracked *.md names a file or folder that exists and, after #, one of its headings."""
import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_every_relative_link_in_every_markdown_file_resolves():
    pages = subprocess.run(["git", "-C", str(ROOT), "ls-files", "*.md"], capture_output=True, text=True,
                           check=True).stdout.split()
    assert "README.md" in pages and "docs/RESULTS.md" in pages
    broken = []
    for page in pages:
        text = re.sub(r"```.*?```", "", (ROOT / page).read_text(), flags=re.S)  # code blocks hold commands, not links
        for link in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", link):
                continue
            target, _, anchor = link.partition("#")
            path = ((ROOT / page).parent / target).resolve() if target else ROOT / page
            if not path.exists():
                broken.append(f"{page}: {link}")
            elif anchor and path.suffix == ".md" and anchor not in {slug(h) for h in
                                                                    re.findall(r"^#+ (.*)$", path.read_text(), re.M)}:
                broken.append(f"{page}: {link} (no such heading)")
    assert not broken, "\n".join(broken)
